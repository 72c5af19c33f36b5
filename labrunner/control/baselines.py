"""Baselines without model-free estimation: open-loop inputs and the valve's feed-forward control.

- ``open-loop``: the input follows the reference trajectory (``steps``, ``sine`` or
  ``setpoints``, in the input's unit), for identification experiments such as the ±6/±12 V steps
  and the 6 V, 1 Hz sine of thesis Sec. 3.2. The controlled outputs are the commanded inputs
  (named ``<input>_cmd``), so the reference is what the rig is driven with.
- ``valve-ffc``: paper 1 eq. (11), i = κ·q_d/√(p_a − p_b) + i_0, with the desired flow q_d from
  the reference [l/min → m³/s], the pressure drop over the valve Δp [Pa] measured (a rig output
  ``dp`` in Pa) or given as ``controller.dp``, κ [A·s·√Pa/m³] and i_0 [A]. The paper prints κ's
  unit garbled; read with SI flows and pressures, κ = 6.596·10⁵ gives currents of i_0 plus a few
  tenths of an ampere for the paper's flows of 1–14 l/min at a few bar, within [i_0, i_max].
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.control.base import Controller
from labrunner.control.factory import Point, Section, input_limits, no_section, reference
from labrunner.control.trajectories import Reference
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigInfo

LPM = 1.0 / 60000.0  # 1 l/min in m³/s
KAPPA_PAPER1 = 6.596e5  # κ of paper 1 Sec. 5.3 [A·s·√Pa/m³]
I0_PAPER1 = 0.53  # i_0 of paper 1 Sec. 5.3 [A]


class OpenLoop(Controller):
    """u[k] = r[k] (B, n_inputs): the reference is the input trajectory itself."""

    def __init__(self, input_names: Sequence[str], u_min: np.ndarray, u_max: np.ndarray) -> None:
        super().__init__([f"{n}_cmd" for n in input_names], u_min, u_max)

    def _reset(self, y0: np.ndarray) -> None:
        self.controlled[...] = self.u_applied

    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        np.clip(r[:, :, 0], self.u_min, self.u_max, out=self.controlled)
        return r[:, :, 0]


class ValveFeedForward(Controller):
    """Paper 1 eq. (11): i = κ q_d/√Δp + i_0 for B runs; κ, i_0, Δp are (B,) arrays."""

    def __init__(
        self,
        *,
        flow_name: str,
        flow_index: int,
        kappa: np.ndarray,
        i_0: np.ndarray,
        u_min: np.ndarray,
        u_max: np.ndarray,
        dp: np.ndarray | None = None,
        dp_index: int | None = None,
    ) -> None:
        super().__init__((flow_name,), u_min, u_max)
        if (dp is None) == (dp_index is None):
            raise InvalidParameter("controller.dp", "give the pressure drop either as a constant or as a rig output")
        B = self.batch
        self.kappa = np.array(kappa, dtype=float).reshape(B, 1)
        self.i_0 = np.array(i_0, dtype=float).reshape(B, 1)
        self._sqrt_dp = None if dp is None else np.sqrt(np.array(dp, dtype=float).reshape(B, 1))
        self._flow = slice(flow_index, flow_index + 1)
        self._dp = None if dp_index is None else slice(dp_index, dp_index + 1)
        self._u = np.zeros((B, 1))

    def _reset(self, y0: np.ndarray) -> None:
        self.controlled[...] = y0[:, self._flow]

    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        self.controlled[...] = y[:, self._flow]
        root = self._sqrt_dp if self._dp is None else np.sqrt(np.maximum(y[:, self._dp], 0.0))
        u = self._u
        np.multiply(self.kappa, r[:, :, 0], out=u)
        u *= LPM
        np.divide(u, root, out=u, where=root > 0.0)
        np.copyto(u, 0.0, where=root <= 0.0)  # no pressure drop (measured): nothing to meter, i = i_0
        u += self.i_0
        return u


def build_open_loop(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[OpenLoop, Reference]:
    """Open-loop input trajectories; keys: u_min, u_max (single-input rigs); reference steps|sine|setpoints."""
    ctl = Section(points, "controller", used=("kind",))
    if len(rig_info.inputs) == 1:
        u_min, u_max = input_limits(ctl, rig_info)
    else:
        u_min, u_max = np.tile(rig_info.input_lo, (len(points), 1)), np.tile(rig_info.input_hi, (len(points), 1))
    ctl.finish()
    no_section(points, "differentiator", "open-loop")
    ref = reference(points, len(rig_info.inputs), kinds=("steps", "sine", "setpoints"))
    return OpenLoop([s.name for s in rig_info.inputs], u_min, u_max), ref


def build_valve_ffc(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[ValveFeedForward, Reference]:
    """Feed-forward of paper 1 eq. (11); keys: output ("flow"), kappa, i_0, dp [Pa], u_min, u_max."""
    ctl = Section(points, "controller", used=("kind",))
    ctl.choice("output", ("flow",), "flow")
    flows = [i for i, s in enumerate(rig_info.outputs) if s.unit == "l/min"]
    if not flows:
        raise InvalidParameter(
            "controller.kind", f"valve-ffc needs a flow output in l/min; rig {rig_info.name!r} has none"
        )
    u_min, u_max = input_limits(ctl, rig_info)
    kappa = ctl.number("kappa", KAPPA_PAPER1, lo=0.0, lo_open=True)
    i_0 = ctl.number("i_0", I0_PAPER1, lo=rig_info.input_lo[0], hi=rig_info.input_hi[0])
    measured = [i for i, s in enumerate(rig_info.outputs) if s.name == "dp" and s.unit == "Pa"]
    if measured and ctl.has("dp"):
        raise InvalidParameter("controller.dp", f"rig {rig_info.name!r} measures the pressure drop; leave dp unset")
    dp = None if measured else ctl.number("dp", lo=0.0, lo_open=True)
    ctl.finish()
    no_section(points, "differentiator", "valve-ffc")
    ref = reference(points, 1)
    flow = rig_info.outputs[flows[0]]
    controller = ValveFeedForward(
        flow_name=flow.name, flow_index=flows[0], kappa=kappa, i_0=i_0, u_min=u_min, u_max=u_max,
        dp=dp, dp_index=measured[0] if measured else None,
    )  # fmt: skip
    return controller, ref
