"""The plate at 32 kHz through the campaign path with its loop on the device: ``labrunner run``
of a campaign on a device-loop rig file, the emulated device in another process; every run's
MCAP holds the twin's outcome and samples. And the plan-time refusal of a host loop the link
cannot carry."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from test_campaign_support import cli

from labrunner import engine
from labrunner.logs import read_run
from labrunner.logs.schema import SAMPLES_SCHEMA_NAME, float32_fields
from labrunner.rigs.registry import load_rig
from tests.test_deviceloop_link import ROOT, emulator_process, rig_file, rig_toml

CAMPAIGN = """
[campaign]
name = "plate-device-loop"
rig = "plate-fd.toml"
fs = 32000.0
seed = 5

[controller]
kind = "plate-mfc"
input = "v"
gamma = 1.0
k_p = 5000.0
k_d = 195.0

[differentiator]
alpha = 4
beta = 4
N = 0
omega_c = 840.0
method = "midpoint"

[reference]
kind = "lift"
lift = 0.1
settle = 0.02
transition = 0.05
hold = 0.02

[grid]
"differentiator.omega_c" = { values = [640.0, 840.0] }
"""


_run = functools.partial(cli, cwd=ROOT, timeout=600)  # the real command, from the repository root


@pytest.mark.slow
def test_plate_campaign_runs_on_the_device(tmp_path: Path):
    with emulator_process(rig_file("plate-mfc", "canfd")) as config:
        (tmp_path / "plate-fd.toml").write_text(rig_toml(config))
        (tmp_path / "campaign.toml").write_text(CAMPAIGN)
        done = _run("run", str(tmp_path / "campaign.toml"), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    logs = sorted((tmp_path / "out" / "runs").glob("*.mcap"))
    assert len(logs) == 2
    twin_rig = load_rig("plate-sim")
    for path in logs:
        log = read_run(str(path))
        point = log.metadata["config"]
        twin = engine.run_batch(
            [point],
            twin_rig,
            fs=32000.0,
            duration=point["campaign"]["duration"],
            seeds=[5],
            rig_safety=config["safety"],
        )[0]
        assert log.outcome["status"] == twin.outcome.status == "completed"
        device = log.metadata["diagnostics"]
        assert device["loop"] == "device" and device["device_loop"]["ticks"] == twin.n_samples
        for name in ("i1", "y1", "ref_y1", "f_hat_y1"):
            np.testing.assert_array_equal(log.frame[name].to_numpy(), np.float32(twin.signals[name]).astype(float))
        # the device's float32 samples are stored as float32 (exactly), its clock as float64
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
        (sample_schema,) = [s for s in summary.schemas.values() if s.name == SAMPLES_SCHEMA_NAME]
        layout = dict(zip(log.names, float32_fields(sample_schema.data, len(log.names))))
        assert layout.pop("t_device") is False and all(layout.values()) and len(layout) == len(log.names) - 1


def test_plan_refuses_the_plate_host_loop_on_a_1_mbit_bus(tmp_path: Path):
    config = rig_file("plate-mfc", "can")
    config["parameters"]["loop"] = "host"
    (tmp_path / "plate-fd.toml").write_text(rig_toml(config))
    (tmp_path / "campaign.toml").write_text(CAMPAIGN)
    for extra in (["--dry-run"], []):
        done = _run("run", str(tmp_path / "campaign.toml"), "--out", str(tmp_path / "out"), *extra)
        assert done.returncode != 0
        # 4 currents in, 4 gap sensors and the trailer out: 32000 × 9 × 135 bits = 38.9 Mbit/s
        assert "campaign.fs: the host loop at 32000 Hz needs 3888% of classic CAN at 1 Mbit/s" in done.stderr
        assert 'loop = "device"' in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_plan_refuses_what_the_device_cannot_run(tmp_path: Path):
    (tmp_path / "plate-fd.toml").write_text(rig_toml(rig_file("plate-mfc", "canfd")))
    (tmp_path / "campaign.toml").write_text(CAMPAIGN + "\n[rig_parameters]\nm = 5.0\n")
    done = _run("run", str(tmp_path / "campaign.toml"), "--dry-run")
    assert done.returncode != 0 and "rig_parameters" in done.stderr


def test_dry_run_counts_the_sample_upload(tmp_path: Path):
    from labrunner.rigs.transports import linkload

    config = rig_file("plate-mfc", "canfd")
    (tmp_path / "plate-fd.toml").write_text(rig_toml(config))
    (tmp_path / "campaign.toml").write_text(CAMPAIGN)
    done = _run("run", str(tmp_path / "campaign.toml"), "--dry-run")
    assert done.returncode == 0, done.stderr
    # 2 points of 0.26 s × 32 kHz × 20 float32 columns, after each run, on CAN FD at 1/5 Mbit/s
    link = linkload.from_rig("can", config["parameters"])
    expected = 2 * linkload.upload_s(link, 32000.0, 0.26, 20)
    assert f"{expected:.0f} s of it sending samples after the runs" in done.stdout
