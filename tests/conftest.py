"""Fixtures shared by the test modules (pytest finds them here; no imports needed)."""

from __future__ import annotations

import os
import signal
import sys
import tempfile
from pathlib import Path

# One BLAS thread a process, as labrunner's own workers run: the suite's workers (one more than the
# cores, below) and the in-process numpy of a test would otherwise each spin a second thread. Set
# before numpy loads; the xdist workers and every child inherit it.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

# Bytecode caching for the suite's processes, in a folder outside the tree: with it turned off
# (PYTHONDONTWRITEBYTECODE, as on this project's machines) each of the hundreds of Python processes
# the suite starts (xdist workers, CLIs, emulators, benchmarks) compiled labrunner's ~33 000 lines
# and pytest rewrote every test module again, ~0.1 s a process. Children inherit it.
if os.environ.pop("PYTHONDONTWRITEBYTECODE", None) is not None:
    os.environ.setdefault("PYTHONPYCACHEPREFIX", str(Path(tempfile.gettempdir()) / f"labrunner-pycache-{os.getuid()}"))
    sys.pycache_prefix, sys.dont_write_bytecode = os.environ["PYTHONPYCACHEPREFIX"], False

import pytest  # noqa: E402 (after the BLAS setting above)
from test_campaign_support import MOTOR_RIG  # noqa: E402

# A suite started with SIGINT ignored (`nohup`, or `&` in a script) passes the ignoring on to every
# child process, and the tests that stop an emulator or a runner with Ctrl-C (SIGINT) then wait for
# children that never stop. A Python handler is reset to the default at exec, so children get
# SIGINT's default back; this process becomes interruptible again too.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker more than the cores this process may use. About a fifth of the suite's
    time is spent waiting, not computing (QEMU, CAN and host-build conform runs in real time, watchdog
    and Ctrl-C tests, benchmarks timing subprocesses): a third worker on two cores fills it."""
    return len(os.sched_getaffinity(0)) + 1


@pytest.fixture
def project(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A project folder (pyproject marker, rigs/motor.toml) as the working directory."""
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "motor.toml").write_text(MOTOR_RIG)
    monkeypatch.chdir(tmp_path)
    return tmp_path
