"""Fixtures shared by the test modules (pytest finds them here; no imports needed)."""

from __future__ import annotations

import signal
from pathlib import Path

import pytest
from test_campaign_support import MOTOR_RIG

# A suite started with SIGINT ignored (`nohup`, or `&` in a script) passes the ignoring on to every
# child process, and the tests that stop an emulator or a runner with Ctrl-C (SIGINT) then wait for
# children that never stop. A Python handler is reset to the default at exec, so children get
# SIGINT's default back; this process becomes interruptible again too.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def project(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A project folder (pyproject marker, rigs/motor.toml) as the working directory."""
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "motor.toml").write_text(MOTOR_RIG)
    monkeypatch.chdir(tmp_path)
    return tmp_path
