"""One build of firmware/ per test session, shared by the pytest-xdist workers and later sessions.

The firmware tests used to build into their own temporary directories: each xdist worker compiled
its own copy (60–125 s on the loaded VM). Now they all build into firmware/build/tests (ignored by
git) under an exclusive lock (fcntl.flock) on a lock file beside it: the first worker builds, the
second waits and then finds every target up to date (make's own check, which makes later sessions
cheap too). One lock per output folder (host, m4), so that the host build need not wait for the
cross-compiler. A missing tool skips, except under LABRUNNER_CI=1, where it fails."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[1] / "firmware"
BUILD = FIRMWARE / "build" / "tests"


def need(*tools: str) -> None:
    """Skip (fail under LABRUNNER_CI=1) when a tool the firmware tests run is not installed."""
    missing = [tool for tool in tools if shutil.which(tool) is None]
    if missing:
        if os.environ.get("LABRUNNER_CI") == "1":
            pytest.fail(f"the firmware tests need {', '.join(missing)} (LABRUNNER_CI=1: no skipping)")
        pytest.skip(f"no {', '.join(missing)}")


def make(folder: str, target: str, timeout: float = 900) -> str:
    """``make -s TARGET BUILD=firmware/build/tests`` under FOLDER's lock (``host`` or ``m4``, the
    output folder the target writes into); its stdout. The lock waits while another worker builds."""
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / f"{folder}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, or when a killed worker dies
        done = subprocess.run(
            ["make", "-s", "-C", str(FIRMWARE), target, f"BUILD={BUILD}"],
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout
