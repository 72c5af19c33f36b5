"""``labrunner check-rig --dead-time``: the delay from an input step to measured motion, on the
rig and on its twin (what the law check and ``conform`` cannot see: docs/control-laws.md).

A device that applies its input late, or a rig slower than its file declares, passes every law
check — the device logs the law's input, and y is measured — while the closed loop it runs is
not the one the campaign was designed on. This runs one small open-loop step (a fraction of the
input range above the safe input, under the rig file's safety routine) on the rig and the same
step on its twin, and compares the responses: the lag that best aligns the rig's normalised
response with the twin's (least squares over whole ticks), and each one's first tick of motion
(beyond 5 σ of the noise before the step and 5 % of the step's response).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from labrunner import engine
from labrunner.rigs.base import RigConfig

STEP_SHARE = 0.1  #: the default step: this share of the input range above the safe input
STEP_AT_S, DURATION_S = 0.1, 0.6  #: the step's time and the run's length [s]
MAX_LAG = 40  #: lags tried, in ticks either way


def step_point(info, step: float | None = None) -> dict[str, Any]:
    """The open-loop point: every input from its safe value to ``step`` (default :data:`STEP_SHARE`)."""
    safe = float(info.safe_input[0])
    level = safe + STEP_SHARE * (float(info.input_hi[0]) - safe) if step is None else float(step)
    return {
        "controller": {"kind": "open-loop"},
        "reference": {"kind": "steps", "levels": [safe, level], "durations": [STEP_AT_S, DURATION_S - STEP_AT_S]},
    }


def _response(y: np.ndarray, k0: int) -> tuple[np.ndarray, float, int | None]:
    """(normalised response from tick k0, its size, its first tick of motion after k0 or None)."""
    base = float(np.mean(y[max(k0 - 10, 0) : k0 + 1]))
    noise = float(np.std(y[: k0 + 1]))
    change = float(y[-1] - base)
    threshold = max(5 * noise, 0.05 * abs(change))
    moved = np.flatnonzero(np.abs(y[k0:] - base) > threshold)
    first = int(moved[0]) if moved.size and abs(change) > 5 * noise else None
    return (y - base) / (change if change else 1.0), abs(change), first


def lag(rig: np.ndarray, twin: np.ndarray, k0: int) -> int:
    """The whole-tick lag d minimising Σ (rig[k] − twin[k − d])² after the step (positive: the rig is later)."""
    n = min(len(rig), len(twin))
    best, err = 0, np.inf
    for d in range(-MAX_LAG, MAX_LAG + 1):
        ks = np.arange(max(k0, k0 + d), n - MAX_LAG)
        e = float(np.mean((rig[ks] - twin[ks - d]) ** 2)) if ks.size else np.inf
        if e < err - 1e-15:
            best, err = d, e
    return best


def compare(y_rig: np.ndarray, y_twin: np.ndarray, fs: float, declared_s: float) -> dict[str, Any]:
    """The verdict on the first output's responses to the step (ticks at ``fs``)."""
    k0 = int(round(STEP_AT_S * fs))
    r_rig, size_rig, first_rig = _response(np.asarray(y_rig, float), k0)
    r_twin, size_twin, first_twin = _response(np.asarray(y_twin, float), k0)
    out: dict[str, Any] = {
        "fs": fs,
        "declared_delay_s": declared_s,
        "rig_motion_after_s": None if first_rig is None else first_rig / fs,
        "twin_motion_after_s": None if first_twin is None else first_twin / fs,
    }
    if first_twin is None or first_rig is None:
        out.update(lag_ticks=None, verdict="not measured", detail="the step moved nothing measurable"
                   f" on the {'twin' if first_twin is None else 'rig'}: give a larger --step")  # fmt: skip
        return out
    d = lag(r_rig, r_twin, k0)
    out["lag_ticks"], out["lag_s"] = d, d / fs
    if d == 0:
        out.update(
            verdict="ok", detail=f"the rig's response lines up with the twin's (declared delay {declared_s:g} s)"
        )
    else:
        out.update(
            verdict="late" if d > 0 else "early",
            detail=f"the rig's response is {abs(d)} tick{'s' if abs(d) > 1 else ''} ({abs(d) / fs * 1e3:.3g} ms) "
            f"{'behind' if d > 0 else 'ahead of'} the twin's (declared delay {declared_s:g} s): the device applies "
            "its input late, or the rig file's delay is wrong — the law check cannot see this",
        )
    return out


def dead_time(config: RigConfig, rig, step: float | None = None, seed: int = 0) -> dict[str, Any]:
    """Run the step on ``rig`` (open, handshaken, the rig file ``config``'s) and on its twin; :func:`compare`."""
    from labrunner.rigs.transports.emulator import twin_for

    twin = twin_for(config)
    info, fs = rig.info, float(rig.info.fs_default)
    point, safety = step_point(info, step), dict(config.safety)
    kw = {"fs": fs, "duration": DURATION_S, "seeds": [seed], "rig_safety": safety}
    [expected] = engine.run_batch([point], twin, **kw)
    if config.parameters.get("loop") == "device":
        [measured] = rig.run_on_device([point], **kw)
    else:
        [measured] = engine.run_batch([point], rig, **kw)
    name = info.outputs[0].name
    declared = float(dict(config.parameters.get("model") or {}).get("sensor_delay", 0.0))
    report = compare(measured.signals[name], expected.signals[name], fs, declared)
    report.update(output=name, step=point["reference"]["levels"][1], rig_outcome=measured.outcome.status)
    return report
