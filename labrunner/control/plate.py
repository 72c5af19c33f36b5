"""Model-free control of the magnetically supported plate: paper 2 Sec. 3.2-3.3.

Three second-order ultra-local models, one per sensor point k ∈ {1, 2, 3}, share the generic
estimator (:class:`~labrunner.control.estimators.MFCEstimator`, eq. (24b), (25)); they differ in
the input x_k the model is written in (``controller.input``):

=========  =============================  ====================  ==========================
input      ultra-local model              law                   currents
=========  =============================  ====================  ==========================
v          ÿ = f_v + γ_v v      (13)      (14)                  f = B†P v (11), i by (12)
force      ÿ = f_F − γ_F F̃      (16)      (17)                  F_4 by (18), i by (12)
u          ÿ = f_u − γ_u (i/h)²           (19)                  u_4 by (18), i = √u · h
current    ÿ = f_i − γ_i(y) i   (20)      (21), γ_i = γ_i,0/y   i_4 by (18)
=========  =============================  ====================  ==========================

All four are u = (ÿ_r − k_p ê − k_d ê̇ − f̂)/γ_s with the signed gain γ_s = γ_v, −γ_F, −γ_u or
−γ_i(y). The estimator sees the *applied* input of the previous tick, recomputed from the
saturated currents and the gaps h = K y (eq. (4)) of that tick. For the current input the
estimator integrates the model's whole input term γ_i(y)·i (γ_i varies with y), which is (24b)
with "v substituted by i" for a constant y. Following eq. (25), only the measurement is filtered
by default (``filter = "output"``): ê = ŷ − y_r, ê̇ = ŷ̇ − ẏ_r. As in Fig. 10b, a notch filter at the
plate's resonance (942 rad/s, :mod:`labrunner.control.plate_filters`) cleans the measurement
before the algebraic differentiators; ``notch_omega = 0`` leaves it out.

The input is chosen per run (:data:`~labrunner.control.factory.PER_RUN_CHOICES`): a batch whose runs
use several laws computes each present law for every row and keeps each row's own, so that a row's
currents are those of a batch of its law alone (the laws are row-wise), and Table 3's four laws
share one lockstep batch instead of four batches of one.

Units are SI throughout. Paper 2's γ_i,0 = 40 works only with y in millimetres in γ_i(y): with
y in metres the equivalent is 0.04 m²/(A s²) (the linearised gain at 2 mm is ≈ 0.023). Eq. (12)
reads i_d = d(h)·√F_d (the extracted text's √(F_d d(h)) is not dimensionally consistent with (2)).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.control.base import Controller
from labrunner.control.estimators import MFCEstimator
from labrunner.control.factory import Point, Section, differentiators
from labrunner.control.plate_filters import StreamingSS, notch_tf, tf_ss, tustin
from labrunner.control.plate_trajectories import reference_from_points
from labrunner.control.trajectories import Reference
from labrunner.differentiators import Differentiator
from labrunner.errors import InvalidParameter
from labrunner.plate_geometry import (
    LAMBDA_INV_SQRT,
    PlateGeometry,
    current_at,
    force_at,
    over_actuation_weights,
)
from labrunner.rigs.base import RigInfo

INPUTS = ("v", "force", "u", "current")


def estimator_gain(input: str, gamma: float) -> float:
    """The signed input gain γ_s of the estimator's model ÿ = f + γ_s x: γ_v, or −γ for the magnet
    inputs; for the current the estimator's input is γ_i(y)·i with γ_s = −1 (see the module docstring)."""
    return gamma if input == "v" else -1.0 if input == "current" else -gamma


class PlateMFC(Controller):
    """Batch MFC of the plate (B runs × 3 sensor points); gains (B,), one differentiator per run.

    ``input`` picks the model (see the module table), one for the batch or one per run; ``weights``
    are the a_k of eq. (18) for the inputs force, u and current; ``y_min`` [m] bounds the sensor
    value in γ_i(y) = γ_i,0 / y (the paper's safety routine keeps the gaps above 0.8 mm).
    """

    model_order = 2  # ÿ_k = f_k + γ u_k (eq. (14))

    def __init__(
        self,
        designs: Sequence[Differentiator],
        *,
        input: str | Sequence[str],
        gamma: np.ndarray,
        k_p: np.ndarray,
        k_d: np.ndarray,
        i_max: np.ndarray,
        geometry: PlateGeometry | None = None,
        lam_inv_sqrt: float = LAMBDA_INV_SQRT,
        weights: Sequence[float] = (0.0, 0.5, 0.5),
        y_min: float | np.ndarray = 0.8e-3,
        filter_error: bool = False,
        notch_omega: float = 942.0,
        notch_q: float = 2.0,
    ) -> None:
        B = len(designs)
        i_max = np.broadcast_to(np.asarray(i_max, dtype=float).reshape(-1, 1), (B, 4))
        super().__init__(("y1", "y2", "y3"), np.zeros((B, 4)), i_max)
        self.inputs = (input,) * B if isinstance(input, str) else tuple(input)
        for name in self.inputs:
            if name not in INPUTS:
                raise InvalidParameter("controller.input", f"must be one of {', '.join(INPUTS)}, got {name!r}")
        if len(self.inputs) != B:
            raise InvalidParameter("controller.input", f"needs one input per run ({B}), got {len(self.inputs)}")
        self._laws = tuple(name for name in INPUTS if name in self.inputs)  # the laws the batch computes
        # with several laws, each one's rows (B, 1): a row keeps its own law's values (None: one law)
        self._rows: list[tuple[str, np.ndarray]] | None = None
        if len(self._laws) > 1:
            self._rows = [(name, np.array([[x == name] for x in self.inputs])) for name in self._laws]
        self.geometry = geometry or PlateGeometry()
        self.lam_inv_sqrt = float(lam_inv_sqrt)
        self.weights = over_actuation_weights(weights)
        col = lambda a: np.array(np.broadcast_to(np.asarray(a, dtype=float).reshape(-1), (B,))).reshape(B, 1)  # noqa: E731
        self.y_min = col(y_min)
        self.gamma, self.k_p, self.k_d = col(gamma), col(k_p), col(k_d)
        self._gamma_est = np.array([[estimator_gain(x, g)] for x, g in zip(self.inputs, self.gamma[:, 0])])
        self.estimator = MFCEstimator(designs, 2, self._gamma_est, 3, filter_error=filter_error)
        self._set_estimates(self.estimator.block, ("f_hat", "e_hat", "de_hat"))
        # gains broadcast to (B, 3) once (a ufunc is cheaper on equal shapes)
        full = lambda a: np.array(np.broadcast_to(a, (B, 3)))  # noqa: E731
        self._gains = np.stack([full(self.k_p), full(self.k_d)])  # (2, B, 3) against (ê, ê̇)
        self._gamma3 = full(self.gamma)
        self._e_hats = self.estimator.block[1:]  # (ê, ê̇), (2, B, 3)
        self._unit_gamma = bool(np.all(self.gamma == 1.0))
        self._P_inv_B_T = self.geometry.P_inv_B.T
        self._V_T = self.geometry.V.T
        self._K_T = self.geometry.K.T
        self._lam_K_T = self.lam_inv_sqrt * self._K_T  # d(h) = λ^(−1/2) K y in one product
        self._weights_col = self.weights[:, None]
        # per-tick scratch, one purpose each
        self._gaps = np.zeros((B, 4))  # h = K y (eq. (4)) at the last tick (input u only)
        self._d_h = np.zeros((B, 4))  # d(h) = λ^(−1/2) h at those gaps
        self._gamma_y = np.zeros((B, 3))  # γ_i(y) at the last tick (input current)
        self._model_x = np.zeros((B, 3))  # the estimator's input x_k of the last applied currents
        self._model_f = np.zeros((B, 4))  # the magnet forces behind it (input v)
        self._ke = np.zeros((2, B, 3))  # (k_p ê, k_d ê̇)
        self._bracket = np.zeros((B, 3))  # ÿ_r − k_p ê − k_d ê̇ − f̂
        self._negative = np.zeros((B, 3))  # its negative, for the magnet inputs
        self._x = np.zeros((B, 3))  # the law's x_k = bracket / γ_s
        self._sum_ax = np.zeros((B, 1))  # Σ a_k x_k of eq. (18)
        self._u = np.zeros((B, 4))  # the four inputs of eq. (18), then the currents of a law
        self._pick_x = np.zeros((B, 3))  # several laws: one law's model input, before the rows keep theirs
        self._pick_u = np.zeros((B, 4))  # several laws: each row's own currents
        self._notch = None
        if notch_omega > 0:
            fs = designs[0].fs
            notch = tustin(tf_ss(*notch_tf(notch_omega, notch_q)), fs, notch_omega)
            self._notch = StreamingSS([notch] * B, channels=3)

    def _filtered(self) -> np.ndarray:
        """This tick's y_1..y_3 (:attr:`controlled`) after the notch filter (Fig. 10b), (B, 3)."""
        if self._notch is None:
            return self.controlled
        return self._notch.step(self.controlled[:, :, None])[:, :, 0]

    def _reset(self, y0: np.ndarray) -> None:
        if self._notch is not None:
            self._notch.reset(y0[:, :3, None])
        self.controlled[...] = y0[:, :3]
        self._measured()
        self.estimator.reset(
            self.controlled, self.controlled, self._model_input(self.u_applied)
        )  # start at rest, e ≡ 0

    def _measured(self) -> None:
        """From this tick's y_1..y_3: the gaps h = K y (eq. (4)), d(h) and γ_i(y) for the law and the next tick."""
        y3 = self.controlled  # a contiguous copy: half the cost of the strided view in a product
        np.dot(y3, self._lam_K_T, out=self._d_h)
        if "u" in self._laws:
            np.dot(y3, self._K_T, out=self._gaps)
        if "current" in self._laws:
            self._gamma_i(y3, out=self._gamma_y)

    def _gamma_i(self, y: np.ndarray, out: np.ndarray) -> np.ndarray:
        """γ_i(y) = γ_i,0 / y, eq. (20)-(21), with y bounded below by ``y_min``."""
        np.maximum(y, self.y_min, out=out)
        return np.divide(self.gamma, out, out=out)

    def _model_input(self, currents: np.ndarray) -> np.ndarray:
        """(B, 3) the applied input x_k of the ultra-local models for ``currents`` at the last gaps,
        each row in its own input."""
        if self._rows is None:
            return self._model_input_as(self._laws[0], currents, self._model_x)
        for name, rows in self._rows:
            np.copyto(self._model_x, self._model_input_as(name, currents, self._pick_x), where=rows)
        return self._model_x

    def _model_input_as(self, input: str, currents: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(B, 3) :meth:`_model_input` of every row as if its input were ``input``, into ``x``."""
        if input == "v":  # v = P⁻¹ B f (eq. (5)) with f = i²/d(h)² (eq. (2))
            return np.dot(force_at(currents, self._d_h, out=self._model_f), self._P_inv_B_T, out=x)
        if input == "force":
            return force_at(currents[:, :3], self._d_h[:, :3], out=x)
        if input == "u":
            return force_at(currents[:, :3], self._gaps[:, :3], out=x)  # (i/h)²
        return np.multiply(self._gamma_y, currents[:, :3], out=x)

    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        est, w, ke = self.estimator, self._bracket, self._ke
        self.controlled[...] = y[:, :3]
        est.step(self._filtered(), self._model_input(self.u_applied), r)  # x_k of the last tick's gaps
        np.multiply(self._gains, self._e_hats, out=ke)  # (k_p ê, k_d ê̇)
        np.subtract(r[:, :, 2], ke[0], out=w)  # w = ÿ_r − k_p ê − k_d ê̇ − f̂
        np.subtract(w, ke[1], out=w)
        np.subtract(w, est.f_hat, out=w)
        self._measured()
        if self._rows is None:
            return self._currents_as(self._laws[0], w)
        for name, rows in self._rows:
            np.copyto(self._pick_u, self._currents_as(name, w), where=rows)
        return self._pick_u

    def _currents_as(self, input: str, w: np.ndarray) -> np.ndarray:
        """(B, 4) the currents of law ``input`` for every row, from w = ÿ_r − k_p ê − k_d ê̇ − f̂."""
        x, u = self._x, self._u
        if input == "v":  # (14): v = w/γ_v; then u = V v (eq. (11)) and the currents by (12)
            np.dot(w if self._unit_gamma else np.divide(w, self._gamma3, out=x), self._V_T, out=u)  # x/1 is x (γ_v = 1)
            return current_at(u, self._d_h, out=u)
        w = np.negative(w, out=self._negative)  # −ÿ_r + k_p ê + k_d ê̇ + f̂
        # (21) with the sign of (17) and (19): i = (1/γ_i(y))(−ÿ_r + k_p ê + k_d ê̇ + f̂_i); the printed
        # extra leading minus would be positive feedback on ÿ = f_i − γ_i(y) i (20)
        if input == "current":
            return self._over_actuated(np.divide(w, self._gamma_y, out=x))
        self._over_actuated(np.divide(w, self._gamma3, out=x))  # (17) or (19): F̃ or u = w/γ, then (18)
        return current_at(u, self._d_h if input == "force" else self._gaps, out=u)  # (12), or i = √u·h (Sec. 3.2.3)

    def _over_actuated(self, x3: np.ndarray) -> np.ndarray:
        """(B, 4) = (x_1, x_2, x_3, Σ a_k x_k) in the input buffer (eq. (18))."""
        u = self._u
        u[:, :3] = x3
        u[:, 3:] = np.dot(x3, self._weights_col, out=self._sum_ax)
        return u


def plate_geometry(rig_info: RigInfo) -> tuple[PlateGeometry, float]:
    """The nominal geometry and λ^(−1/2) of the rig (its constants), or paper 2's Table 2."""
    c = rig_info.constants
    keys = ("m", "g", "J_x", "J_y", "l_dx", "l_dy", "l_fx", "l_fy")
    geometry = PlateGeometry(**{k: float(c[k]) for k in keys if k in c})
    return geometry, float(c.get("lambda_inv_sqrt", LAMBDA_INV_SQRT))


def check_plate_rig(rig_info: RigInfo, kind: str) -> None:
    """Plate controllers need four current inputs and at least the three sensors of eq. (4)."""
    if len(rig_info.inputs) != 4 or len(rig_info.outputs) < 3:
        raise InvalidParameter(
            "controller.kind", f"{kind!r} needs a plate rig (4 currents, >= 3 sensors), got rig {rig_info.name!r}"
        )


def build_plate_mfc(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[PlateMFC, Reference]:
    """Plate MFC from campaign points; ``controller`` keys: ``input`` (v | force | u | current,
    default v), ``gamma``, ``k_p``, ``k_d``, ``filter`` (output | error, default output),
    ``weights`` (a_k of eq. (18), not for input v), ``i_max`` [A], ``y_min`` [m] (input current),
    ``notch_omega`` [rad/s] (942; 0: no notch) and ``notch_q`` (2) of the measurement's notch.
    The input may differ between the runs (:data:`~labrunner.control.factory.PER_RUN_CHOICES`)."""
    check_plate_rig(rig_info, "plate-mfc")
    ctl = Section(points, "controller", used=("kind",))
    inputs = ctl.choice("input", INPUTS, "v", per_run=True)

    def set_without(key: str, laws: tuple[str, ...]) -> bool:
        """Whether a run whose input is none of ``laws`` sets ``key``."""
        return any(x not in laws and key in row for x, row in zip(inputs, ctl.rows))

    gamma = ctl.number("gamma", lo=0.0, lo_open=True)
    k_p = ctl.number("k_p", lo=0.0)
    k_d = ctl.number("k_d", lo=0.0)
    filter_error = ctl.choice("filter", ("output", "error"), "output") == "error"
    i_hi = float(rig_info.input_hi.min())
    i_max = ctl.number("i_max", i_hi, lo=0.0, lo_open=True, hi=i_hi)
    weights = (0.0, 0.5, 0.5)
    if ctl.has("weights"):
        if set_without("weights", ("force", "u", "current")):
            raise InvalidParameter(
                "controller.weights",
                "input 'v' allocates by the pseudo-inverse (eq. (11)); weights are for force, u, current",
            )
        used = [row for x, row in zip(inputs, ctl.values("weights", weights)) if x != "v"]
        try:
            rows = [over_actuation_weights(row) for row in used]
        except InvalidParameter as exc:
            raise InvalidParameter("controller.weights", exc.message) from None
        if any(not np.array_equal(row, rows[0]) for row in rows):
            raise InvalidParameter("controller.weights", "must be the same for every run of a batch")
        weights = tuple(rows[0])
    notch_omega = ctl.number("notch_omega", 942.0, lo=0.0, hi=np.pi * fs)
    notch_q = ctl.number("notch_q", 2.0, lo=0.0, lo_open=True)
    for key, values in (("notch_omega", notch_omega), ("notch_q", notch_q)):
        if np.ptp(values) > 0:
            raise InvalidParameter(f"controller.{key}", "must be the same for every run of a batch")
    if set_without("y_min", ("current",)):
        raise InvalidParameter("controller.y_min", "bounds y in γ_i(y) = γ_i,0 / y of input 'current' only")
    y_min = ctl.number("y_min", 0.8e-3, lo=0.0, lo_open=True)
    ctl.finish()
    designs = differentiators(points, fs, 2)
    ref = reference_from_points(points, rig_info, delays_s=np.array([d.discrete_delay_s(0) for d in designs]))
    geometry, lam = plate_geometry(rig_info)
    controller = PlateMFC(
        designs, input=inputs, gamma=gamma, k_p=k_p, k_d=k_d, i_max=i_max,
        geometry=geometry, lam_inv_sqrt=lam, weights=weights, y_min=y_min, filter_error=filter_error,
        notch_omega=float(notch_omega[0]), notch_q=float(notch_q[0]),
    )  # fmt: skip
    return controller, ref
