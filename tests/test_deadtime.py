"""``check-rig --dead-time`` (docs/control-laws.md, "What the checks do not cover"): a device that
applies its input a tick late passes ``conform`` and every law check, and the dead-time step
catches it; the comparison itself on synthetic responses."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from labrunner.rigs.transports import deadtime
from tests.test_deviceloop_link import ROOT, emulator_process, rig_file, rig_toml

FS = 200.0


def _step_response(lag_ticks: int, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    k = np.arange(int(deadtime.DURATION_S * FS))
    k0 = int(deadtime.STEP_AT_S * FS) + lag_ticks
    y = np.where(k > k0, 1.0 - np.exp(-(k - k0) / 8.0), 0.0)
    return y + noise * np.random.default_rng(seed).normal(size=k.size)


@pytest.mark.parametrize("lag", [0, 1, 3])
def test_the_lag_of_a_delayed_response_is_found_to_the_tick(lag):
    report = deadtime.compare(_step_response(lag, 0.002, 1), _step_response(0, 0.002, 2), FS, 0.0)
    assert report["lag_ticks"] == lag
    assert report["verdict"] == ("ok" if lag == 0 else "late")
    if lag:
        assert f"{lag} tick" in report["detail"] and "the law check cannot see this" in report["detail"]


def test_a_step_that_moves_nothing_is_not_measured():
    report = deadtime.compare(_step_response(0) * 0.0, _step_response(0), FS, 0.0)
    assert report["verdict"] == "not measured" and "on the rig" in report["detail"]


def _check_rig(tmp_path, config: dict) -> tuple[int, dict]:
    path = tmp_path / "rig.toml"
    path.write_text(rig_toml(config))
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "check-rig", str(path), "--pings", "5", "--dead-time", "--json"],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )  # fmt: skip
    assert done.stdout, done.stderr
    return done.returncode, json.loads(done.stdout)["dead_time"]


def _conform(tmp_path, config: dict) -> tuple[int, dict]:
    from tests.test_conform import _conform as run

    return run(tmp_path, config, "--no-protocol")


@pytest.mark.slow
@pytest.mark.parametrize("loop", ["device", "host"])
def test_a_device_applying_its_input_a_tick_late_passes_conform_and_the_dead_time_test_catches_it(tmp_path, loop):
    config = rig_file("motor-mfc1", "can")
    config["parameters"]["loop"] = loop
    with emulator_process(config, ("--input-delay", "1")) as served:
        # conform (always the device loop) against this emulator: `emulate` does not read the rig
        # file's loop, so the [host] case would repeat the [device] case's conform exactly; run once
        if loop == "device":
            conformed, report = _conform(tmp_path, {**served, "parameters": {**served["parameters"], "loop": loop}})
            assert conformed == 0 and report["passed"], [c for c in report["checks"] if not c["passed"]]
        code, late = _check_rig(tmp_path, served)
    assert code == 1 and late["verdict"] == "late" and late["lag_ticks"] == 1, late
    with emulator_process(config) as served:
        code, fine = _check_rig(tmp_path, served)
    assert code == 0 and fine["verdict"] == "ok" and fine["lag_ticks"] == 0, fine
    assert fine["rig_motion_after_s"] == fine["twin_motion_after_s"]
    assert late["rig_motion_after_s"] == pytest.approx(fine["rig_motion_after_s"] + 1 / FS)
