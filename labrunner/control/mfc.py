"""Model-free control of first and second order with the generalised unknown-part estimate.

First order (thesis (2.35), discrete (3.3)–(3.4); paper 1 eq. (16))::

    u[k] = (1/γ)(ẏ_r[k] − k_p ê[k] − f̂[k])

second order (thesis (2.49); paper 2 eqs. (14), (25))::

    u[k] = (1/γ)(ÿ_r[k] − k_d ê̇[k] − k_p ê[k] − f̂[k])

with f̂, ê, ê̇ from :class:`~labrunner.control.estimators.MFCEstimator` (ε = t_s). The
controlled output is a rig output read directly (angle θ, valve flow q) or the difference quotient
Ω[k] = (θ[k] − θ[k−1])/t_s of the angle (thesis (2.34)) for motor velocity control. The input is
saturated to [u_min, u_max] by :class:`~labrunner.control.base.Controller` and the estimator uses
the applied (saturated) input. Valve option (paper 1 Sec. 4.4.3–4.4.4): the minimal current
``i_min`` is the lower saturation bound and the current is set to ``i_min`` whenever the desired
flow is ≤ 0.

Units: γ relates the output's n-th derivative to the input (motor: rad/(V s²)); for the valve it
is given in paper 1's m³/(A s²) and converted to the l/min of the flow signal (× 60 000).

Kinds: ``mfc1``, ``mfc2`` and ``mfc1-ff``, the k_p = 0 "feed-forward tuning" law of Polack et al.
(thesis (3.11)), which is ``mfc1`` with k_p fixed at 0 (a ``k_p`` key is rejected).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.control.base import Controller
from labrunner.control.estimators import MFCEstimator
from labrunner.control.factory import Point, Section, differentiators, input_limits, reference
from labrunner.control.trajectories import Reference
from labrunner.differentiators import Differentiator
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigInfo


@dataclass(frozen=True)
class OutputMap:
    """The controlled output: rig output column ``index``, read directly or differenced (2.34)."""

    name: str
    index: int
    difference: bool = False
    gamma_scale: float = 1.0  # controller.gamma × gamma_scale = γ in the output's own unit
    unit: str = ""  # SI unit of the controlled output (the rig output's, per second when differenced)


#: controller.output → (rig output unit, difference quotient?, model orders allowed, γ scale)
OUTPUTS = {
    "velocity": ("rad", True, (1,), 1.0),  # Ω from θ by (2.34), first-order model (2.32)
    "angle": ("rad", False, (2,), 1.0),  # θ, second-order model (2.47)
    # valve flow q in l/min, first-order model (paper 1 eq. (13)); γ as paper 1 gives it, in
    # m³/(A s²) (γ = 0.4, Sec. 5.3), is 60 000 × larger in (l/min)/(A s)
    "flow": ("l/min", False, (1,), 60_000.0),
}


#: unit of ``controller.gamma`` where it is not the controlled output's own (paper 1 gives γ in SI)
GAMMA_UNITS = {"flow": "m³/(A·s²)"}


def gamma_scale(output: str | None) -> float:
    """Factor from ``controller.gamma`` (the campaign's unit) to γ in the controlled output's unit."""
    return OUTPUTS[output][3] if output in OUTPUTS else 1.0


def resolve_output(output: str | None, rig_info: RigInfo, order: int) -> OutputMap:
    """Map ``controller.output`` to a rig output; without it, the rig's only output, read directly."""
    if output is None:
        if len(rig_info.outputs) != 1:
            raise InvalidParameter(
                "controller.output", f"is required for rig {rig_info.name!r}: one of {', '.join(OUTPUTS)}"
            )
        return OutputMap(rig_info.outputs[0].name, 0, unit=rig_info.outputs[0].unit)
    unit, difference, orders, scale = OUTPUTS[output]
    if order not in orders:
        raise InvalidParameter(
            "controller.output", f"{output!r} needs an ultra-local model of order {orders[0]}, got order {order}"
        )
    for index, sig in enumerate(rig_info.outputs):
        if sig.unit == unit:
            if difference:
                return OutputMap("omega", index, True, scale, f"{sig.unit}/s")
            return OutputMap(sig.name, index, False, scale, sig.unit)
    raise InvalidParameter(
        "controller.output", f"{output!r} needs a rig output in {unit}; rig {rig_info.name!r} has none"
    )


class MFC(Controller):
    """Single-output MFC of order 1 or 2 for B runs; gains are (B,) arrays, designs one per run.

    ``u_init`` (B, 1) is the input of the stationary past the estimator's history starts from
    (default 0: a plant at rest with no input).
    """

    def __init__(
        self,
        designs: Sequence[Differentiator],
        order: int,
        *,
        gamma: np.ndarray,
        k_p: np.ndarray,
        k_d: np.ndarray | None,
        u_min: np.ndarray,
        u_max: np.ndarray,
        output: OutputMap,
        filter_error: bool | np.ndarray = True,
        i_min: np.ndarray | None = None,
        u_init: np.ndarray | None = None,
    ) -> None:
        super().__init__((output.name,), u_min, u_max, u_init, output_units=(output.unit,))
        if self.n_inputs != 1:
            raise InvalidParameter("controller.kind", "MFC here is single-input; use a plate kind for the plate")
        B = self.batch
        self.model_order, self.output = order, output
        self.fs = designs[0].fs
        self.gamma = np.array(gamma, dtype=float).reshape(B, 1)
        self.k_p = np.array(k_p, dtype=float).reshape(B, 1)
        self.k_d = None if k_d is None else np.array(k_d, dtype=float).reshape(B, 1)
        if order == 2 and self.k_d is None:
            raise InvalidParameter("controller.k_d", "is required for a second-order law")
        self.i_min = None if i_min is None else np.array(i_min, dtype=float).reshape(B, 1)
        self.estimator = MFCEstimator(designs, order, self.gamma, filter_error=filter_error)
        self._set_estimates(self.estimator.block, ("f_hat", "e_hat", "de_hat")[: 1 + order])
        self._col = slice(output.index, output.index + 1)
        self._difference = output.difference
        self._fs = np.array(self.fs)  # a 0-d array multiplies faster than a Python float
        self._prev = np.zeros((B, 1))
        self._u = np.zeros((B, 1))
        self._tmp = np.zeros((B, 1))
        self._inv_gamma = 1.0 / self.gamma
        self._kp_gamma = self.k_p / self.gamma
        self._kd_gamma = None if self.k_d is None else self.k_d / self.gamma

    def _reset(self, y0: np.ndarray) -> None:
        if self.output.difference:
            self._prev[...] = y0[:, self._col]
            self.controlled[...] = 0.0  # a stationary start: Ω = 0
        else:
            self.controlled[...] = y0[:, self._col]
        self.estimator.reset(self.controlled, self.controlled, self.u_applied)  # zero initial error

    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        c, est, u, tmp = self.controlled, self.estimator, self._u, self._tmp
        y_out = y[:, self._col]
        if self._difference:  # (2.34)
            np.subtract(y_out, self._prev, out=c)
            np.multiply(c, self._fs, out=c)
            self._prev[...] = y_out
        else:
            c[...] = y_out
        est.step(c, self.u_applied, r)
        np.subtract(r[:, :, self.model_order], est.f_hat, out=u)  # (y_r⁽ⁿ⁾ − f̂ − k_p ê − k_d ê̇)/γ
        np.multiply(u, self._inv_gamma, out=u)
        np.multiply(self._kp_gamma, est.e_hat, out=tmp)
        np.subtract(u, tmp, out=u)
        if self._kd_gamma is not None:
            np.multiply(self._kd_gamma, est.de_hat, out=tmp)
            np.subtract(u, tmp, out=u)
        if self.i_min is not None:  # paper 1 Sec. 4.4.4: i = i_min where the desired flow is zero
            np.copyto(u, self.i_min, where=r[:, :, 0] <= 0.0)
        return u


def _build(
    points: Sequence[Point], rig_info: RigInfo, fs: float, order: int, *, with_k_p: bool = True
) -> tuple[MFC, Reference]:
    ctl = Section(points, "controller", used=("kind",))
    output = resolve_output(ctl.choice("output", tuple(OUTPUTS)) if ctl.has("output") else None, rig_info, order)
    gamma = ctl.number("gamma", lo=0.0, lo_open=True) * output.gamma_scale
    k_p = ctl.number("k_p", lo=0.0) if with_k_p else np.zeros(len(points))
    k_d = ctl.number("k_d", lo=0.0) if order == 2 else None
    filter_error = np.array(ctl.choice("filter", ("error", "output"), "error", per_run=True)) == "error"
    i_min = None
    if ctl.has("i_min"):
        if rig_info.outputs[output.index].unit != "l/min":
            raise InvalidParameter("controller.i_min", "is the valve's minimal current; use u_min for other rigs")
        if ctl.has("u_min"):
            raise InvalidParameter("controller.i_min", "give either i_min or u_min, not both")
        i_min = ctl.number("i_min", lo=rig_info.input_lo[0], hi=rig_info.input_hi[0])
    u_min, u_max = input_limits(ctl, rig_info, lo=i_min)
    ctl.finish()
    designs = differentiators(points, fs, order)
    ref = reference(points, 1, delays_s=np.array([d.discrete_delay_s(0) for d in designs]))
    controller = MFC(
        designs, order, gamma=gamma, k_p=k_p, k_d=k_d, u_min=u_min, u_max=u_max,
        output=output, filter_error=filter_error, i_min=i_min,
    )  # fmt: skip
    return controller, ref


def build_mfc1(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[MFC, Reference]:
    """First-order MFC (thesis (2.35)/(3.3)); keys: output, gamma, k_p, filter, u_min, u_max, i_min.

    ``gamma`` is in the unit of the output's derivative per input unit, except for ``output =
    "flow"``, where it is in paper 1's m³/(A s²) (the flow itself stays in l/min).
    """
    return _build(points, rig_info, fs, 1)


def build_mfc1_ff(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[MFC, Reference]:
    """Polack et al.'s feed-forward tuning law, k_p = 0 (thesis (3.11)); keys as mfc1 without k_p."""
    return _build(points, rig_info, fs, 1, with_k_p=False)


def build_mfc2(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[MFC, Reference]:
    """Second-order MFC (thesis (2.49); paper 2 eq. (14)/(25)); keys as mfc1 plus k_d."""
    return _build(points, rig_info, fs, 2)
