"""Conformance vectors of the device loop's laws (``labrunner vectors``; format in
docs/control-laws.md, "Conformance vectors").

Each case is a campaign point on a simulated twin: the twin's closed-loop run gives y[k]
(float64), the run description carries that y as its SENSOR_TABLE, and the reference loop run
on that table (:func:`labrunner.rigs.device.replay.replay`, holding the last row as a device
does) gives the expected logged rows and the verdict. The cases cover every kind the device
loop accepts, each plate-mfc input, the valve's i_min, a ``du_dt`` abort and a no-motion run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from labrunner import engine
from labrunner.control import factory
from labrunner.rigs.config import load_rig_config
from labrunner.rigs.device import description
from labrunner.rigs.device.columns import column_names
from labrunner.rigs.device.replay import replay, stack_signals
from labrunner.rigs.registry import load_rig

_MOTOR_DIFF = {"alpha": 4, "beta": 4, "N": 0, "omega_c": 150.0, "method": "midpoint"}
_MOTOR_REF = {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 0.3, "hold": 0.1}
_PLATE_DIFF = {"alpha": 4, "beta": 4, "N": 0, "omega_c": 840.0, "method": "midpoint"}
_PLATE_REF = {"kind": "lift", "lift": 0.004, "settle": 0.001, "transition": 0.002, "hold": 0.001}
_VALVE_REF = {"kind": "setpoints", "levels": [1.0, 5.0, 0.0], "transition": 0.1, "hold": 0.05}


_MOTOR_SINE = {"kind": "sine", "amplitude": 6.0, "frequency": 1.0, "duration": 1.0}
_VALVE_FFC = {"kind": "valve-ffc", "dp": 3.0e5}


def _plate_mfc(input: str, gamma: float, **safety: object) -> dict[str, object]:
    return {
        "controller": {"kind": "plate-mfc", "input": input, "gamma": gamma, "k_p": 5000.0, "k_d": 195.0},
        "differentiator": dict(_PLATE_DIFF),
        "reference": dict(_PLATE_REF),
        **({"safety": safety} if safety else {}),
    }


def _open_loop(reference: Mapping[str, object], **safety: object) -> dict[str, object]:
    return {"controller": {"kind": "open-loop"}, "reference": dict(reference), **({"safety": safety} if safety else {})}


def _valve_ffc(**safety: object) -> dict[str, object]:
    return {"controller": dict(_VALVE_FFC), "reference": dict(_VALVE_REF), **({"safety": safety} if safety else {})}


def _mfc1_motor(**safety: object) -> dict[str, object]:
    return {
        "controller": {"kind": "mfc1", "output": "velocity", "gamma": 108.55, "k_p": 30.0},
        "differentiator": dict(_MOTOR_DIFF),
        "reference": dict(_MOTOR_REF),
        **({"safety": safety} if safety else {}),
    }


@dataclass(frozen=True)
class Case:
    """One conformance vector: a point on a simulated rig at ``fs`` for ``duration`` s."""

    point: Mapping[str, object]
    rig: str
    fs: float
    duration: float
    seed: int = 1
    nan_at: tuple[int, int] | None = None  #: (tick, output): the sensor reads NaN there (a sensor fault)


#: name → case (the shipped set, docs/vectors/)
CASES: dict[str, Case] = {
    "mfc1-motor-velocity": Case(
        {"controller": {"kind": "mfc1", "output": "velocity", "gamma": 108.55, "k_p": 30.0},
         "differentiator": dict(_MOTOR_DIFF), "reference": dict(_MOTOR_REF)},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "mfc1-ff-motor-velocity": Case(
        {"controller": {"kind": "mfc1-ff", "output": "velocity", "gamma": 108.55},
         "differentiator": dict(_MOTOR_DIFF), "reference": dict(_MOTOR_REF)},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "mfc2-motor-angle": Case(
        {"controller": {"kind": "mfc2", "output": "angle", "gamma": 108.55, "k_p": 400.0, "k_d": 40.0,
                        "filter": "output"},
         "differentiator": {"alpha": 9, "beta": 9, "N": 0, "omega_c": 200.0, "method": "analytic"},
         "reference": {"kind": "setpoints", "levels": [0.0, 6.283185307179586], "transition": 0.5, "hold": 0.1}},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "mfc1-motor-du_dt-abort": Case(
        {"controller": {"kind": "mfc1", "output": "velocity", "gamma": 10.0, "k_p": 300.0},
         "differentiator": {"alpha": 2, "beta": 2, "N": 0, "omega_c": 300.0, "method": "midpoint"},
         "reference": {"kind": "setpoints", "levels": [0.0, 40.0, 0.0], "transition": 0.3, "hold": 0.25}},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "open-loop-motor-sine": Case(
        {"controller": {"kind": "open-loop"},
         "reference": {"kind": "sine", "amplitude": 6.0, "frequency": 1.0, "duration": 1.0}},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "open-loop-motor-no-motion": Case(
        {"controller": {"kind": "open-loop"}, "reference": {"kind": "steps", "levels": [0.0, 0.0], "durations": [0.5, 0.5]}},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "mfc1-valve-i_min": Case(
        {"controller": {"kind": "mfc1", "output": "flow", "gamma": 0.4, "k_p": 30.0, "i_min": 0.5},
         "differentiator": {"alpha": 2, "beta": 2, "N": 0, "omega_c": 250.0, "method": "midpoint"},
         "reference": dict(_VALVE_REF)},
        "valve-sim", 4000.0, 0.35,
    ),
    "valve-ffc": Case(
        {"controller": {"kind": "valve-ffc", "dp": 3.0e5}, "reference": dict(_VALVE_REF)}, "valve-sim", 4000.0, 0.35,
    ),
    "plate-mfc-v": Case(_plate_mfc("v", 1.0), "plate-sim", 32000.0, 0.01),
    "plate-mfc-force": Case(_plate_mfc("force", 1.0), "plate-sim", 32000.0, 0.01),
    "plate-mfc-u": Case(_plate_mfc("u", 1.6e-5), "plate-sim", 32000.0, 0.01),
    "plate-mfc-current": Case(_plate_mfc("current", 0.04), "plate-sim", 32000.0, 0.01),
    "plate-mbc": Case({"controller": {"kind": "plate-mbc"}, "reference": dict(_PLATE_REF)}, "plate-sim", 32000.0, 0.01),
    # every law feature and safety monitor for every rig kind (docs/control-laws.md, "Coverage")
    "mfc1-motor-saturation": Case(
        {"controller": {"kind": "mfc1", "output": "velocity", "gamma": 40.0, "k_p": 60.0, "u_min": -2.0, "u_max": 9.0},
         "differentiator": dict(_MOTOR_DIFF),
         "reference": {"kind": "setpoints", "levels": [0.0, 60.0, 0.0], "transition": 0.15, "hold": 0.25},
         "safety": {"max_du_dt": 1.0e6}},
        "dcmotor-sim", 200.0, 1.0,
    ),
    "open-loop-motor-steps": Case(
        _open_loop({"kind": "steps", "levels": [1.0, 3.0, 2.0], "durations": [0.3, 0.3, 0.4]}, max_du_dt=1.0e6),
        "dcmotor-sim", 200.0, 1.0,
    ),
    "open-loop-motor-input_high": Case(_open_loop(_MOTOR_SINE, input_bounds={"u": [-12.0, 4.0]}), "dcmotor-sim", 200.0, 1.0),
    "open-loop-motor-input_low": Case(_open_loop(_MOTOR_SINE, input_bounds={"u": [-4.0, 12.0]}), "dcmotor-sim", 200.0, 1.0),
    "open-loop-motor-output_low": Case(
        _open_loop({"kind": "steps", "levels": [0.0, -6.0], "durations": [0.1, 0.9]}, output_bounds={"theta": [-0.5, 100.0]},
                   max_du_dt=1.0e6),
        "dcmotor-sim", 200.0, 1.0,
    ),
    "mfc1-motor-output_high": Case(_mfc1_motor(output_bounds={"theta": [-100.0, 1.0]}), "dcmotor-sim", 200.0, 1.0),
    "mfc1-motor-non_finite_input": Case(_mfc1_motor(), "dcmotor-sim", 200.0, 1.0, nan_at=(50, 0)),
    "open-loop-motor-non_finite_output": Case(_open_loop(_MOTOR_SINE), "dcmotor-sim", 200.0, 1.0, nan_at=(50, 0)),
    "open-loop-motor-run_time": Case(_open_loop(_MOTOR_SINE, max_duration=0.5), "dcmotor-sim", 200.0, 1.0),
    "open-loop-motor-no-motion-level": Case(_open_loop(_MOTOR_SINE, motion_min_level=100.0), "dcmotor-sim", 200.0, 1.0),
    "valve-ffc-saturation": Case(
        {"controller": dict(_VALVE_FFC),
         "reference": {"kind": "setpoints", "levels": [1.0, 30.0, 1.0], "transition": 0.1, "hold": 0.05}},
        "valve-sim", 4000.0, 0.35,
    ),
    "valve-ffc-output_high": Case(_valve_ffc(output_bounds={"q": [-1.0, 4.0]}), "valve-sim", 4000.0, 0.35),
    "valve-ffc-output_low": Case(_valve_ffc(output_bounds={"q": [0.5, 100.0]}), "valve-sim", 4000.0, 0.35),
    "valve-ffc-input_high": Case(_valve_ffc(input_bounds={"i": [0.0, 0.6]}), "valve-sim", 4000.0, 0.35),
    "valve-ffc-input_low": Case(_valve_ffc(input_bounds={"i": [0.54, 1.01]}), "valve-sim", 4000.0, 0.35),
    "valve-ffc-du_dt": Case(_valve_ffc(max_du_dt=5.0), "valve-sim", 4000.0, 0.35),
    "mfc1-valve-non_finite_input": Case({
        "controller": {"kind": "mfc1", "output": "flow", "gamma": 0.4, "k_p": 30.0, "i_min": 0.5},
        "differentiator": {"alpha": 2, "beta": 2, "N": 0, "omega_c": 250.0, "method": "midpoint"},
        "reference": dict(_VALVE_REF)}, "valve-sim", 4000.0, 0.35, nan_at=(600, 0)),
    "valve-ffc-non_finite_output": Case(_valve_ffc(), "valve-sim", 4000.0, 0.35, nan_at=(600, 0)),
    "valve-ffc-run_time": Case(_valve_ffc(max_duration=0.2), "valve-sim", 4000.0, 0.35),
    "open-loop-valve-no-motion": Case(
        _open_loop({"kind": "steps", "levels": [0.2, 0.3], "durations": [0.1, 0.25]}), "valve-sim", 4000.0, 0.35
    ),
    "plate-mfc-derived-output_low": Case(
        _plate_mfc("v", 1.0, output_bounds={f"h{j}": [5.3e-3, 5.6e-3] for j in range(1, 5)}), "plate-sim", 32000.0, 0.01
    ),
    "plate-mfc-derived-output_high": Case(
        _plate_mfc("v", 1.0, output_bounds={f"h{j}": [0.8e-3, 5.5e-3] for j in range(1, 5)}), "plate-sim", 32000.0, 0.01
    ),
    "plate-mfc-output_low": Case(_plate_mfc("v", 1.0, output_bounds={"y2": [5.3e-3, 1.0]}), "plate-sim", 32000.0, 0.01),
    "plate-mfc-output_high": Case(_plate_mfc("v", 1.0, output_bounds={"y3": [0.0, 5.5e-3]}), "plate-sim", 32000.0, 0.01),
    "plate-mfc-input_high": Case(
        _plate_mfc("v", 1.0, input_bounds={f"i{j}": [0.0, 6.0] for j in range(1, 5)}), "plate-sim", 32000.0, 0.01
    ),
    "plate-mbc-input_low": Case(
        {"controller": {"kind": "plate-mbc"}, "reference": dict(_PLATE_REF),
         "safety": {"input_bounds": {f"i{j}": [0.1, 8.0] for j in range(1, 5)}}},
        "plate-sim", 32000.0, 0.01,
    ),
    "plate-mfc-du_dt": Case(_plate_mfc("force", 1.0, max_du_dt=2.0e3, du_dt_omega_c=8000.0), "plate-sim", 32000.0, 0.01),
    "plate-mfc-non_finite_input": Case(_plate_mfc("v", 1.0), "plate-sim", 32000.0, 0.01, nan_at=(100, 1)),
    "plate-mfc-non_finite_output": Case(_plate_mfc("v", 1.0), "plate-sim", 32000.0, 0.01, nan_at=(100, 3)),
    "plate-mfc-run_time": Case(_plate_mfc("v", 1.0, max_duration=0.005), "plate-sim", 32000.0, 0.01),
    "plate-mbc-no-motion": Case(
        {"controller": {"kind": "plate-mbc"}, "reference": dict(_PLATE_REF), "safety": {"motion_min_change": 1.0}},
        "plate-sim", 32000.0, 0.01,
    ),
    "plate-mbc-no-motion-level": Case(
        {"controller": {"kind": "plate-mbc"}, "reference": dict(_PLATE_REF), "safety": {"motion_min_level": 1.0}},
        "plate-sim", 32000.0, 0.01,
    ),
}  # fmt: skip


@dataclass
class Vector:
    """A case's description (with its sensor table), its logged columns and rows, and the verdict."""

    data: bytes
    columns: list[str]
    rows: np.ndarray  # (n, columns) float64: the sensor table's columns and the expected ones
    outcome: engine.Outcome


def rig_safety(case: Case) -> dict[str, object]:
    """The ``[safety]`` of the case's shipped rig file."""
    return dict(load_rig_config(case.rig).safety)


def build(case: Case) -> Vector:
    """The vector of ``case``: the twin's y, the description carrying it, the expected rows."""
    rig = load_rig(case.rig)
    safety = rig_safety(case)
    point = dict(case.point)
    twin = engine.run_batch([point], rig, fs=case.fs, duration=case.duration, seeds=[case.seed], rig_safety=safety)[0]
    y = np.stack([twin.signals[s.name] for s in rig.info.outputs], axis=1)
    if case.nan_at is not None:
        y[case.nan_at] = np.nan
    data = description.build(
        point, rig.info, fs=case.fs, duration=case.duration, seed=case.seed, rig_safety=safety, sensor_table=y
    )
    [run] = replay(
        point, rig.info, y[None], fs=case.fs, duration=case.duration, seed=case.seed, rig_safety=safety, hold_last=True
    )
    controller, _ = factory.build([point], rig.info, case.fs)
    names = column_names(engine.channel_names(rig.info, controller))
    return Vector(data, names, stack_signals(run, names), run.outcome)


def _number(x: float | None) -> str:
    return "nan" if x is None or math.isnan(x) else f"{x:.17g}"


def csv_text(vector: Vector) -> str:
    """``vector.csv``: the header ``k,<columns>`` and one line per logged tick."""
    lines = [",".join(["k", *vector.columns])]
    lines += [",".join([str(k), *(_number(float(v)) for v in row)]) for k, row in enumerate(vector.rows)]
    return "\n".join(lines) + "\n"


def verdict_text(vector: Vector) -> str:
    """``verdict.txt``: ``key = value`` lines."""
    o = vector.outcome
    items = {
        "status": o.status,
        "monitor": o.monitor or "nan",
        "samples": str(len(vector.rows)),
        "time": _number(o.time),
        "value": _number(o.value),
        "threshold": _number(o.threshold),
        "message": o.message or "nan",
    }
    return "".join(f"{k} = {v}\n" for k, v in items.items())


def description_text(data: bytes) -> str:
    """``description.txt``: the decoded description, one line per header field and record."""
    d = description.decode(data)
    lines = [
        f"magic = LRDL, version = {description.VERSION}, bytes = {len(data)}, stream = {int(d.stream)}",
        f"RUN: fs = {d.fs!r} Hz, duration = {d.duration!r} s, ticks = {d.ticks}, seed = {d.seed}, "
        f"watchdog = {d.watchdog_s!r} s, inputs = {d.n_inputs}, outputs = {d.n_outputs}, columns = {d.n_columns}",
        f"KIND: {d.kind}",
    ]
    lines += [f"PARAM {s}.{k} = {v!r}" for s, section in d.sections.items() for k, v in section.items()]
    lines += [f"FIR purpose {p} order {n}: L = {w.size}, w = {_array(w)}" for (p, n), w in sorted(d.fir.items())]
    if d.saturation is not None:
        lines.append(f"SATURATION: u_min = {_array(d.saturation[0])}, u_max = {_array(d.saturation[1])}")
    lines += [f"BOUNDS kind {k}: lo = {_array(lo)}, hi = {_array(hi)}" for k, (lo, hi) in sorted(d.bounds.items())]
    if d.rate is not None:
        lines.append("RATE: max |du/dt| = {!r}, alpha = {!r}, beta = {!r}, omega_c = {!r}".format(*d.rate))
    lines.append(f"MAX_DURATION: {d.max_duration!r} s")
    lines += [
        f"TRAJECTORY output {j} type {c}: " + "; ".join(map(_array, a)) for j, (c, a) in enumerate(d.trajectories)
    ]
    if d.derived is not None:
        lines.append(f"DERIVED: {_array(d.derived)}")
    lines += [f"FILTER {name}: M {m.shape[0]}x{m.shape[1]} = {_array(m)}" for name, m in d.filters.items()]
    lines += [f"LAW {name} ({a.shape[0]}x{a.shape[1]}) = {_array(a)}" for name, a in d.law.items()]
    if d.motion is not None:
        lines.append("MOTION: output {}, rule {}, threshold {!r}".format(*d.motion))
    if d.sensor_table is not None:
        lines.append(f"SENSOR_TABLE: {d.sensor_table.shape[0]} rows x {d.sensor_table.shape[1]} outputs (vector.csv)")
    return "\n".join(lines) + "\n"


def _array(a: np.ndarray) -> str:
    return "[" + ", ".join(_number(float(x)) for x in np.ravel(a)) + "]"


def write(out: Path, names: list[str] | None = None) -> list[Path]:
    """Write the vectors of ``names`` (default: every case) under ``out``; the directories written."""
    written = []
    for name in names or list(CASES):
        vector = build(CASES[name])
        folder = Path(out) / name
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "description.bin").write_bytes(vector.data)
        (folder / "description.txt").write_text(description_text(vector.data))
        (folder / "vector.csv").write_text(csv_text(vector))
        (folder / "verdict.txt").write_text(verdict_text(vector))
        written.append(folder)
    return written
