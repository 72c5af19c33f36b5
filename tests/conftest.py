"""Fixtures shared by the test modules (pytest finds them here; no imports needed)."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_campaign_support import MOTOR_RIG


@pytest.fixture
def project(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A project folder (pyproject marker, rigs/motor.toml) as the working directory."""
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (tmp_path / "rigs").mkdir()
    (tmp_path / "rigs" / "motor.toml").write_text(MOTOR_RIG)
    monkeypatch.chdir(tmp_path)
    return tmp_path
