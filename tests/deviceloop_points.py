"""Campaign points of the device-loop tests: the shipped campaigns' controllers on the three rigs."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from labrunner import engine
from labrunner.rigs.registry import load_rig

MOTOR_SAFETY = {
    "max_du_dt": 120.0,
    "input_bounds": {"u": [-12.0, 12.0]},
    "max_duration": 60.0,
    "motion_output": "theta",
}
_SETPOINTS = {"kind": "setpoints", "levels": [0.0, 6.283185307179586, 0.0], "transition": 0.5, "hold": 0.25}
_PLATE_BOUNDS = {
    "output_bounds": {f"h{j}": [0.8e-3, 5.6e-3] for j in range(1, 5)},
    "input_bounds": {f"i{j}": [0.0, 8.0] for j in range(1, 5)},
    "max_duration": 30.0,
    "motion_output": "y1",
}
_PLATE_REF = {"kind": "lift", "lift": 0.1, "settle": 0.02, "transition": 0.05, "hold": 0.02}

#: name → (point, rig, fs, duration, rig safety)
POINTS = {
    "motor-mfc1": (
        {
            "controller": {"kind": "mfc1", "output": "velocity", "gamma": 108.55, "k_p": 30.0},
            "differentiator": {"alpha": 4, "beta": 4, "N": 0, "omega_c": 150.0, "method": "midpoint"},
            "reference": {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 0.5, "hold": 0.25},
            "safety": {},
        },
        "dcmotor-sim",
        200.0,
        2.0,
        MOTOR_SAFETY,
    ),
    "motor-mfc2": (
        {
            "controller": {"kind": "mfc2", "output": "angle", "gamma": 108.55, "k_p": 400.0, "k_d": 40.0},
            "differentiator": {"alpha": 9, "beta": 9, "N": 0, "omega_c": 200.0, "method": "analytic"},
            "reference": _SETPOINTS,
            "safety": {"max_du_dt": 120.0},
        },
        "dcmotor-sim",
        200.0,
        2.0,
        MOTOR_SAFETY,
    ),
    "motor-aborted": (
        {
            "controller": {"kind": "mfc1", "output": "velocity", "gamma": 10.0, "k_p": 300.0},
            "differentiator": {"alpha": 2, "beta": 2, "N": 0, "omega_c": 300.0, "method": "midpoint"},
            "reference": {"kind": "setpoints", "levels": [0.0, 40.0, 0.0], "transition": 0.3, "hold": 0.25},
            "safety": {},
        },
        "dcmotor-sim",
        200.0,
        2.0,
        MOTOR_SAFETY,
    ),
    "motor-open-loop": (
        {
            "controller": {"kind": "open-loop"},
            "reference": {"kind": "steps", "levels": [0.0, 6.0], "durations": [0.5, 1.5]},
            "safety": {"max_du_dt": 1.0e6},
        },
        "dcmotor-sim",
        200.0,
        2.0,
        MOTOR_SAFETY,
    ),
    "valve-mfc1": (
        {
            "controller": {"kind": "mfc1", "output": "flow", "gamma": 0.4, "k_p": 30.0, "i_min": 0.5},
            "differentiator": {"alpha": 2, "beta": 2, "N": 0, "omega_c": 250.0, "method": "midpoint"},
            "reference": {"kind": "setpoints", "levels": [1.0, 5.0, 1.0], "transition": 0.2, "hold": 0.1},
            "safety": {},
        },
        "valve-sim",
        4000.0,
        0.5,
        {"input_bounds": {"i": [0.0, 1.01]}, "max_duration": 120.0, "motion_output": "q", "motion_min_level": 1.2},
    ),
    "plate-mfc": (
        {
            "controller": {"kind": "plate-mfc", "input": "v", "gamma": 1.0, "k_p": 5000.0, "k_d": 195.0},
            "differentiator": {"alpha": 4, "beta": 4.0, "N": 0, "omega_c": 840.0, "method": "midpoint"},
            "reference": _PLATE_REF,
            "safety": {},
        },
        "plate-sim",
        32000.0,
        0.25,
        _PLATE_BOUNDS,
    ),
    "plate-mbc": (
        {"controller": {"kind": "plate-mbc"}, "reference": _PLATE_REF, "safety": {}},
        "plate-sim",
        32000.0,
        0.25,
        _PLATE_BOUNDS,
    ),
}


@functools.cache
def twin_run(name: str, seed: int) -> engine.RunResult:
    """The twin engine's run of a point (B = 1)."""
    point, rig, fs, duration, safety = POINTS[name]
    return engine.run_batch([point], load_rig(rig), fs=fs, duration=duration, seeds=[seed], rig_safety=safety)[0]


def assert_same_as_twin(result: engine.RunResult, name: str, seed: int) -> None:
    """A device run of point ``name`` is the twin's: same outcome, channels and length; every
    sample the twin's rounded once to float32, the errors e = y − y_r of those samples; the
    metrics within what that rounding moves them."""
    twin = twin_run(name, seed)
    assert result.outcome == twin.outcome and result.channels == twin.channels
    assert result.n_samples == twin.n_samples
    f32 = {k: np.float32(v).astype(float) for k, v in twin.signals.items()}
    for key, value in f32.items():
        o = key[2:] if key.startswith("e_") else None
        expected = f32[o] - f32[f"ref_{o}"] if o in twin.signals and f"ref_{o}" in twin.signals else value
        np.testing.assert_array_equal(result.signals[key], expected, err_msg=key)
    for key, value in twin.metrics.items():
        assert result.metrics[key] == pytest.approx(value, rel=1e-4, abs=1e-9, nan_ok=True), key
