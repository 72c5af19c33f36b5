"""Model-based control (MBC) of the magnetically supported plate: paper 2 Sec. 3.1 and 4.2.

Per sensor point k ∈ {1, 2, 3} (model (6): ÿ = v + g + η):

* flatness-based feedback (7): v = ÿ_r − c_D (ŷ̇ − ẏ_r) − c_P (ŷ − y_r) − g − η̂;
* linear disturbance observer (10) of x = (y, ẏ, η) with the triple-integrator model (9), gains
  l from the error eigenvalues −820, −840, −860 1/s;
* a notch filter (Tietze & Schenk Sec. 13.8) at the plate's resonance 942 rad/s on the measurement;
* low-pass filters on the observer's estimates so that their stop-band slopes match the algebraic
  differentiator's 20(μ − n) dB/decade, μ = 1 + min(α, β) (Fig. 9, 10a): Butterworth of order
  μ − 1 − n on the estimate of y⁽ⁿ⁾ (the observer alone falls with 20 dB/decade on each);
* all continuous parts discretised by Tustin's method, each prewarped at its own cutoff;
* forces by the pseudo-inverse (11), currents by (12) with d(h) = λ^(−1/2) h and the gaps (4).

The observer's input is the *applied* v[k−1] = P⁻¹ B f(i_applied[k−1], h[k−1]) (saturated
currents), one sample late, which breaks the algebraic loop of Tustin's direct feed-through.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.control.base import Controller
from labrunner.control.factory import Point, Section, no_section
from labrunner.control.plate import check_plate_rig, plate_geometry
from labrunner.control.plate_filters import (
    StateSpace,
    StreamingSS,
    identity,
    lowpass_tf,
    notch_tf,
    parallel,
    series,
    tf_ss,
    tustin,
)
from labrunner.control.plate_trajectories import reference_from_points
from labrunner.control.trajectories import Reference
from labrunner.errors import InvalidParameter, check_finite
from labrunner.plate_geometry import LAMBDA_INV_SQRT, PlateGeometry, current_at, force_at
from labrunner.rigs.base import RigInfo


@dataclass(frozen=True)
class MBCDesign:
    """Parameters of the MBC's estimation chain and feedback (paper 2 Sec. 4.2), SI units.

    ``lowpass_orders`` are the Butterworth orders on (ŷ, ŷ̇, η̂); :func:`matched_orders` derives
    them from the algebraic differentiator's α, β. ``notch_q`` is the notch's quality factor
    ω_0 / bandwidth (the paper does not give it).
    """

    fs: float = 32_000.0
    c_p: float = 5000.0
    c_d: float = 195.0
    observer_poles: tuple[float, float, float] = (820.0, 840.0, 860.0)
    notch_omega: float = 942.0
    notch_q: float = 2.0
    lowpass_omega: float = 840.0
    lowpass_orders: tuple[int, int, int] = (4, 3, 2)

    def __post_init__(self) -> None:
        nyquist = np.pi * check_finite("fs", self.fs)
        for name in ("c_p", "c_d", "notch_q"):
            if not check_finite(name, getattr(self, name)) > 0:
                raise InvalidParameter(name, f"must be > 0, got {getattr(self, name)!r}")
        frequencies = {"notch_omega": self.notch_omega, "lowpass_omega": self.lowpass_omega}
        if len(self.observer_poles) != 3:
            raise InvalidParameter("observer_poles", f"needs three values, got {self.observer_poles!r}")
        frequencies.update({f"observer_poles[{i}]": p for i, p in enumerate(self.observer_poles)})
        for name, value in frequencies.items():
            if not 0 < check_finite(name, value) < nyquist:
                raise InvalidParameter(name, f"must be in (0, π fs = {nyquist:.0f}) rad/s, got {value!r}")
        if len(self.lowpass_orders) != 3 or any(int(q) != q or not 0 <= q <= 8 for q in self.lowpass_orders):
            raise InvalidParameter("lowpass_orders", f"needs three integers in [0, 8], got {self.lowpass_orders!r}")

    @property
    def observer_warp(self) -> float:
        """Prewarp frequency of the observer: its cutoff, the mean eigenvalue magnitude [rad/s]."""
        return float(np.mean(self.observer_poles))


def matched_orders(alpha: float, beta: float) -> tuple[int, int, int]:
    """Low-pass orders on (ŷ, ŷ̇, η̂) matching the differentiator's slopes 20(μ − n) dB/dec, μ = 1 + min(α, β)."""
    mu = 1 + int(np.floor(min(alpha, beta)))
    return tuple(max(mu - 1 - n, 0) for n in range(3))  # type: ignore[return-value]


def observer_gains(poles: Sequence[float]) -> np.ndarray:
    """l = (l_1, l_2, l_3) placing the eigenvalues of A − l cᵀ (eq. (9), (10)) at −poles [1/s]."""
    return np.poly(-np.asarray(poles, dtype=float))[1:]


def observer_ss(poles: Sequence[float]) -> StateSpace:
    """Continuous observer (10): inputs (y, v + g), outputs x̂ = (ŷ, ŷ̇, η̂)."""
    a = np.diag([1.0, 1.0], k=1)
    l = observer_gains(poles)
    A = a - np.outer(l, [1.0, 0.0, 0.0])
    B = np.column_stack([l, [0.0, 1.0, 0.0]])
    return A, B, np.eye(3), np.zeros((3, 2))


def estimation_chain(design: MBCDesign) -> dict[str, StateSpace]:
    """The discretised parts of Fig. 10a: ``notch`` (y → y_n), ``observer`` ((y_n, v+g) → x̂),
    ``lowpass`` (x̂ → filtered x̂) and ``chain``: the whole (y, v + g) → (ŷ, ŷ̇, η̂)."""
    fs = design.fs
    notch = tustin(tf_ss(*notch_tf(design.notch_omega, design.notch_q)), fs, design.notch_omega)
    observer = tustin(observer_ss(design.observer_poles), fs, design.observer_warp)
    lowpass = parallel(
        [tustin(tf_ss(*lowpass_tf(q, design.lowpass_omega)), fs, design.lowpass_omega) for q in design.lowpass_orders]
    )
    chain = series(series(parallel([notch, identity()]), observer), lowpass)
    return {"notch": notch, "observer": observer, "lowpass": lowpass, "chain": chain}


class PlateMBC(Controller):
    """Batch MBC of the plate: B runs, per-run gains c_P, c_D (B,); one estimation chain per run.

    Outputs y_1..y_3 (the sensors of eq. (4)); inputs the four currents [A] in [0, ``i_max``].
    Estimates for logging: ``f_hat`` = η̂ + g (comparable with the MFC's f̂_v, Fig. 15),
    ``e_hat`` = ŷ − y_r, ``de_hat`` = ŷ̇ − ẏ_r.
    """

    model_order = 2  # f̂ = η̂ + g is an acceleration, as the MFC's f̂_v

    def __init__(
        self,
        designs: Sequence[MBCDesign],
        geometry: PlateGeometry | None = None,
        *,
        lam_inv_sqrt: float = LAMBDA_INV_SQRT,
        i_max: float | np.ndarray = 8.0,
    ) -> None:
        B = len(designs)
        i_max = np.broadcast_to(np.asarray(i_max, dtype=float).reshape(-1, 1), (B, 4))
        super().__init__(("y1", "y2", "y3"), np.zeros((B, 4)), i_max)
        self.geometry = geometry or PlateGeometry()
        self.lam_inv_sqrt = float(lam_inv_sqrt)
        self.c_p = np.array([[d.c_p] for d in designs])
        self.c_d = np.array([[d.c_d] for d in designs])
        chains = {d: estimation_chain(d)["chain"] for d in set(designs)}  # one design per distinct run
        self._chain = StreamingSS([chains[d] for d in designs], channels=3)
        self._set_estimates(np.zeros((3, B, 3)), ("f_hat", "e_hat", "de_hat"))
        # per-tick buffers; gains broadcast to (B, 3) once (a ufunc is cheaper on equal shapes)
        self._c_p3, self._c_d3 = np.repeat(self.c_p, 3, axis=1), np.repeat(self.c_d, 3, axis=1)
        self._g = np.array(self.geometry.g)
        self._K_T, self._P_inv_B_T, self._V_T = self.geometry.K.T, self.geometry.P_inv_B.T, self.geometry.V.T
        self._lam_h = np.zeros((B, 4))  # d(h) = λ^(−1/2) h at the last tick's gaps (eq. (4))
        self._v, self._t, self._f = np.zeros((B, 3)), np.zeros((B, 3)), np.zeros((B, 4))

    def _measured(self, y: np.ndarray) -> None:
        """Keep this tick's y_1..y_3 and d(h) at the gaps h = K y (eq. (4)) for the law and the next tick."""
        y3 = self.controlled
        y3[...] = y[:, :3]
        np.dot(y3, self._K_T, out=self._lam_h)  # from the contiguous copy: half the cost of the strided view
        np.multiply(self.lam_inv_sqrt, self._lam_h, out=self._lam_h)

    def _reset(self, y0: np.ndarray) -> None:
        self._measured(y0)
        w = np.empty((self.batch, 3, 2))  # chain inputs per sensor point: (y, v + g)
        w[:, :, 0] = y0[:, :3]
        w[:, :, 1] = self.geometry.g  # at rest: v = 0
        self._chain.reset(w)

    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        chain, v, t, f, g = self._chain, self._v, self._t, self._f, self._g
        w = chain.input  # (B, 3, 2): y and the applied v + g of the last tick, eq. (5)
        w[:, :, 0] = y[:, :3]
        np.dot(force_at(self.u_applied, self._lam_h, out=f), self._P_inv_B_T, out=t)
        np.add(t, g, out=w[:, :, 1])
        x_hat = chain.advance()  # (B, 3, 3): ŷ, ŷ̇, η̂ per sensor point
        e_hat, de_hat, f_hat = self.estimates["e_hat"], self.estimates["de_hat"], self.estimates["f_hat"]
        np.subtract(x_hat[:, :, 0], r[:, :, 0], out=e_hat)
        np.subtract(x_hat[:, :, 1], r[:, :, 1], out=de_hat)
        np.multiply(self._c_d3, de_hat, out=t)  # eq. (7): v = ÿ_r − c_D ê̇ − c_P ê − g − η̂
        np.subtract(r[:, :, 2], t, out=v)
        np.multiply(self._c_p3, e_hat, out=t)
        np.subtract(v, t, out=v)
        np.subtract(v, g, out=v)
        np.subtract(v, x_hat[:, :, 2], out=v)
        np.add(x_hat[:, :, 2], g, out=f_hat)
        self._measured(y)
        return current_at(np.dot(v, self._V_T, out=f), self._lam_h, out=f)  # eq. (11), (12)


def build_plate_mbc(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[PlateMBC, Reference]:
    """Plate MBC from campaign points; ``controller`` keys (defaults: paper 2 Sec. 4.2): ``c_p``
    [1/s²] 5000, ``c_d`` [1/s] 195, ``observer_poles`` [1/s] [820, 840, 860], ``notch_omega``
    [rad/s] 942, ``notch_q`` 2, ``lowpass_omega`` [rad/s] 840, ``match_alpha`` 4 (the α = β of
    the differentiator whose slopes the low-pass filters match), ``i_max`` [A]. No
    ``differentiator`` section; the reference cannot be delayed (the MBC's delay is unknown)."""
    check_plate_rig(rig_info, "plate-mbc")
    no_section(points, "differentiator", "plate-mbc")
    ctl = Section(points, "controller", used=("kind",))
    c_p = ctl.number("c_p", 5000.0, lo=0.0, lo_open=True)
    c_d = ctl.number("c_d", 195.0, lo=0.0, lo_open=True)
    poles = ctl.values("observer_poles", [820.0, 840.0, 860.0])
    notch = ctl.number("notch_omega", 942.0, lo=0.0, lo_open=True)
    q = ctl.number("notch_q", 2.0, lo=0.0, lo_open=True)
    lp = ctl.number("lowpass_omega", 840.0, lo=0.0, lo_open=True)
    alpha = ctl.number("match_alpha", 4.0, lo=0.0, hi=8.0)
    i_hi = float(rig_info.input_hi.min())
    i_max = ctl.number("i_max", i_hi, lo=0.0, lo_open=True, hi=i_hi)
    ctl.finish()
    designs = []
    for i in range(len(points)):
        if np.ndim(poles[i]) != 1 or len(poles[i]) != 3:  # type: ignore[arg-type]
            raise InvalidParameter(
                "controller.observer_poles", f"needs three eigenvalue magnitudes [1/s], got {poles[i]!r}"
            )
        try:
            designs.append(
                MBCDesign(fs=fs, c_p=c_p[i], c_d=c_d[i], observer_poles=tuple(float(p) for p in poles[i]),  # type: ignore[union-attr]
                          notch_omega=notch[i], notch_q=q[i], lowpass_omega=lp[i], lowpass_orders=matched_orders(alpha[i], alpha[i]))
            )  # fmt: skip
        except InvalidParameter as exc:
            raise InvalidParameter(f"controller.{exc.field.split('[')[0]}", exc.message) from None
    geometry, lam = plate_geometry(rig_info)
    controller = PlateMBC(designs, geometry, lam_inv_sqrt=lam, i_max=i_max)
    return controller, reference_from_points(points, rig_info, delays_s=None)
