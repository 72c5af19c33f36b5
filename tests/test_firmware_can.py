"""The C device core on a CAN bus through python-can (part 7 of issue 33): the host build's
shared library under firmware/port/can/can_bridge.py on a udp_multicast bus; ``labrunner
conform`` passes every check over CAN FD and classic CAN, and a wrong law fails. A missing C
compiler skips, except under LABRUNNER_CI=1, where it fails."""

from __future__ import annotations

import contextlib
import json
import random
import subprocess
import sys
from pathlib import Path

import pytest

from tests.firmware_build import BUILD, make, need
from tests.test_deviceloop_link import rig_toml

ROOT = Path(__file__).resolve().parents[1]
SAFETY = {"max_du_dt": 120.0, "input_bounds": {"u": [-12.0, 12.0]}, "max_duration": 60.0, "motion_output": "theta"}


@pytest.fixture(scope="module")
def lib() -> Path:
    need("make", "cc")
    target = BUILD / "host" / "liblabdevice_can.so"
    make("host", str(target))
    return target


@contextlib.contextmanager
def _bridge(lib: Path, tmp_path: Path, fd: bool, *args: str):
    """The core on a fresh udp_multicast bus; yields the rig file's path."""
    config = {
        "rig": {"kind": "can", "name": "dcmotor-canfd" if fd else "dcmotor-can"},
        "parameters": {
            "device": "dcmotor", "node_id": 9, "loop": "device", "interface": "udp_multicast",
            "channel": "239.74.163.3", "port": random.randint(20000, 60000), "bitrate": 1_000_000, "fd": fd,
            "data_bitrate": 5_000_000,
        },
        "safety": SAFETY,
    }  # fmt: skip
    path = tmp_path / "rig.toml"
    path.write_text(rig_toml(config))
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "firmware" / "port" / "can" / "can_bridge.py"), str(lib), str(path), *args],
        stdout=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout.readline().strip() == "serving"
        yield path
    finally:
        proc.kill()  # power off: a device busy with a run's upload hears no signal until it gives up (10 s)
        proc.wait(timeout=10)


def _conform(rig: Path, *args: str) -> dict:
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "conform", str(rig), "--json", *args],
        capture_output=True, text=True, cwd=ROOT, timeout=900,
    )  # fmt: skip
    report = json.loads(done.stdout)
    report["code"] = done.returncode
    return report


@pytest.mark.slow
@pytest.mark.parametrize("fd", [True, False], ids=["canfd", "classic"])
def test_conform_passes_every_check_against_the_core_on_can(lib, tmp_path, fd):
    with _bridge(lib, tmp_path, fd) as rig:
        report = _conform(rig)
    failed = [c for c in report["checks"] if not c["passed"]]
    assert report["code"] == 0 and not failed and len(report["checks"]) == 28, failed


def test_a_wrong_law_on_can_fails_its_vector(lib, tmp_path):
    with _bridge(lib, tmp_path, True, "--fault-law", "gamma=1.01") as rig:
        report = _conform(rig, "--case", "mfc1-motor-velocity", "--no-protocol")
    assert report["code"] == 1
    assert {c["name"]: c["passed"] for c in report["checks"]} == {
        "handshake": True,
        "vector mfc1-motor-velocity": False,
    }
