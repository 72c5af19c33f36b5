"""The run description's law records: the resolved constants of the law, the no-motion rule and
the optional sensor table (pure; record layouts in docs/device-loop.md, their use in
docs/control-laws.md).

* LAW (type 14): one named constant of the law as the engine's factory resolved it — defaults
  filled in, units converted (the valve's γ in (l/min)/(A·s)), the plate's geometry matrices —
  so a firmware reads numbers, never defaults or designs;
* MOTION (type 13): which output the no-motion rule watches, how, and its threshold (the rig's
  sensor resolution when the safety sections name none);
* SENSOR_TABLE (type 12): y[k] for the device to read instead of its sensors (conformance runs:
  the law runs, no plant moves); row min(k, n − 1) at tick k.
"""

from __future__ import annotations

import struct

import numpy as np

from labrunner.control.base import Controller
from labrunner.rigs.base import RigInfo
from labrunner.safety import SafetyConfig

R_SENSOR_TABLE, R_MOTION, R_LAW = 12, 13, 14
#: MOTION rules: the output moved by more than the threshold from its first value / rose above it
MOTION_CHANGE, MOTION_LEVEL = 0, 1
#: plate-mfc's ``input`` as the LAW constant ``input`` codes it
PLATE_INPUTS = ("v", "force", "u", "current")


def law_constants(controller: Controller) -> dict[str, np.ndarray]:
    """Name → (rows, columns) float64 of every constant the law of a B = 1 ``controller`` uses
    beyond the FIR, FILTER, SATURATION and TRAJECTORY records (docs/control-laws.md lists them per kind)."""
    from labrunner.control.baselines import ValveFeedForward
    from labrunner.control.mfc import MFC
    from labrunner.control.plate import PlateMFC
    from labrunner.control.plate_mbc import PlateMBC

    c: dict[str, object] = {}
    if isinstance(controller, MFC):
        c.update(
            gamma=controller.gamma[0, 0],
            k_p=controller.k_p[0, 0],
            output_index=controller.output.index,
            difference=float(controller.output.difference),
            filter_error=controller.estimator._m[0, 0],
        )
        if controller.k_d is not None:
            c["k_d"] = controller.k_d[0, 0]
        if controller.i_min is not None:
            c["i_min"] = controller.i_min[0, 0]
    elif isinstance(controller, ValveFeedForward):
        c.update(kappa=controller.kappa[0, 0], i_0=controller.i_0[0, 0], flow_index=controller._flow.start)
        if controller._dp is not None:
            c["dp_index"] = controller._dp.start
        else:
            c["dp"] = controller._sqrt_dp[0, 0] ** 2
    elif isinstance(controller, (PlateMFC, PlateMBC)):
        g = controller.geometry
        c.update(lambda_inv_sqrt=controller.lam_inv_sqrt, K=g.K, V=g.V, P_inv_B=g.P_inv_B)
        if isinstance(controller, PlateMFC):
            c.update(
                input=PLATE_INPUTS.index(controller.inputs[0]),
                gamma=controller.gamma[0, 0],
                k_p=controller.k_p[0, 0],
                k_d=controller.k_d[0, 0],
                filter_error=controller.estimator._m[0, 0],
                weights=controller.weights[None, :],
                y_min=controller.y_min[0, 0],
            )
        else:
            c.update(c_p=controller.c_p[0, 0], c_d=controller.c_d[0, 0], g=g.g)
    return {k: np.atleast_2d(np.asarray(v, float)) for k, v in c.items()}


def motion_rule(config: SafetyConfig, info: RigInfo) -> tuple[int, int, float]:
    """(output index, rule, threshold) of the no-motion rule, as the engine applies it."""
    names = [s.name for s in info.outputs]
    j = names.index(config.motion_output) if config.motion_output else 0
    if config.motion_min_level is not None:
        return j, MOTION_LEVEL, float(config.motion_min_level)
    change = config.motion_min_change if config.motion_min_change is not None else info.outputs[j].resolution
    return j, MOTION_CHANGE, float(change)


def encode(kind: int, value: object) -> bytes:
    """The value bytes of a record of ``kind``: LAW (name, array), MOTION (index, rule, threshold)
    or SENSOR_TABLE (rows (n, n_outputs))."""
    if kind == R_LAW:
        name, array = value  # type: ignore[misc]
        raw, a = name.encode("ascii"), np.atleast_2d(np.asarray(array, "<f8"))
        return struct.pack("<BBB", len(raw), *a.shape) + raw + a.tobytes()
    if kind == R_MOTION:
        return struct.pack("<BBd", *value)  # type: ignore[misc]
    rows = np.asarray(value, "<f8")
    return struct.pack("<BI", rows.shape[1], rows.shape[0]) + rows.tobytes()


def decode_into(kind: int, value: bytes, out: dict[str, object]) -> None:
    """Store a decoded LAW, MOTION or SENSOR_TABLE record in ``out`` (``law``, ``motion``, ``sensor_table``)."""
    if kind == R_LAW:
        n, rows, cols = struct.unpack_from("<BBB", value)
        name = value[3 : 3 + n].decode("ascii")
        out.setdefault("law", {})[name] = np.frombuffer(value, "<f8", rows * cols, 3 + n).reshape(rows, cols).copy()  # type: ignore[union-attr]
    elif kind == R_MOTION:
        j, rule, threshold = struct.unpack("<BBd", value)
        out["motion"] = (j, rule, threshold)
    else:
        n_out, n = struct.unpack_from("<BI", value)
        out["sensor_table"] = np.frombuffer(value, "<f8", n * n_out, 5).reshape(n, n_out).copy()
