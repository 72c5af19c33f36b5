"""Shared helpers of the campaign tests (no tests here): campaign text, CLI runs, ledger rows.

The ``project`` fixture (a small project folder with ``rigs/motor.toml``) is in ``conftest.py``.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from labrunner.rigs.base import RigInfo
from labrunner.rigs.sim.dcmotor import DCMotorTwin

ROOT = Path(__file__).resolve().parents[1]

MOTOR_RIG = """\
[rig]
kind = "dcmotor"
description = "test motor: the thesis's a and b, default friction and noise"

[parameters]
a = 39.44
b = 108.55

[safety]
max_du_dt = 120.0
motion_output = "theta"
"""


GRID = '"controller.gamma" = { log10 = [1.5, 3.0], num = 3 }\n"controller.k_p" = { log10 = [0.0, 2.0], num = 3 }'


def campaign_text(
    name: str = "tiny",
    *,
    rig: str = "rigs/motor.toml",
    duration: float | None = 2.0,
    seed: int = 3,
    hold: float = 0.25,
    grid: str = GRID,
    extra: str = "",
) -> str:
    """A first-order MFC velocity campaign (thesis Sec. 3.5.1 settings, shortened reference: 0.5 s
    transitions, ``hold`` s at each level); ``duration=None`` runs for the reference's length."""
    length = "" if duration is None else f"duration = {duration}\n"
    return f"""\
[campaign]
name = "{name}"
description = "test campaign"
rig = "{rig}"
fs = 200.0
{length}seed = {seed}

[controller]
kind = "mfc1"
output = "velocity"
gamma = 108.55
k_p = 50.0

[differentiator]
alpha = 9
beta = 9
N = 0
omega_c = 200.0
method = "midpoint"

[reference]
kind = "setpoints"
levels = [0.0, 20.0, 0.0]
transition = 0.5
hold = {hold}

[safety]
max_du_dt = 120.0

[grid]
{grid}
{extra}"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def cli(*args: str, cwd: Path, timeout: float = 120.0, **kw) -> subprocess.CompletedProcess:
    """The real ``labrunner`` command in a subprocess."""
    return subprocess.run(
        [sys.executable, "-m", "labrunner", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, **kw
    )


def spawn(*args: str, cwd: Path) -> subprocess.Popen:
    """``labrunner`` in its own session (so a signal to its group reaches it like a terminal's Ctrl-C)."""
    return subprocess.Popen(
        [sys.executable, "-m", "labrunner", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def ledger_rows(directory: Path) -> list[dict]:
    """Every ledger row as a dict (read-only connection; safe while a runner writes)."""
    path = directory / "ledger.sqlite"
    if not path.exists():
        return []
    db = sqlite3.connect(f"{path.as_uri()}?mode=ro", uri=True, timeout=30)
    db.row_factory = sqlite3.Row
    try:
        return [dict(r) for r in db.execute("SELECT * FROM points ORDER BY seq")]
    except sqlite3.OperationalError:
        return []
    finally:
        db.close()


def wait_for(predicate, timeout: float, interval: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return False


def _without_provenance(outcome: dict | None) -> dict | None:
    """An outcome record less ``recovered``: a run whose log was published before a kill and
    adopted on resume is the same run, only committed later."""
    return outcome if outcome is None else {k: v for k, v in outcome.items() if k != "recovered"}


def comparable(rows: list[dict]) -> list[tuple]:
    """What must agree between two runs of one campaign: states, outcomes and metrics per point."""
    return [
        (
            r["id"],
            r["parameters"],
            r["state"],
            r["outcome"],
            _without_provenance(json.loads(r["outcome_json"] or "null")),
            r["rms_error"],
            r["input_energy"],
            r["max_abs_input"],
            r["log_path"],
        )
        for r in rows
    ]


class InProcessMotor(DCMotorTwin):
    """The motor twin declared a *real* rig (``simulated = False``): it must run in-process, one at a time."""

    KIND = "inprocess-motor"

    @classmethod
    def nominal_info(cls, name, description, parameters) -> RigInfo:
        info = super().nominal_info(name, description, parameters)
        return RigInfo(**{**info.__dict__, "simulated": False})


def env_without_pythonpath() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


class BusOffMotor(InProcessMotor):
    """A real rig whose bus fails after 0.1 s: the stop-campaign tier (architecture, "Safety")."""

    KIND = "busoff-motor"

    def _step(self, u):
        if self.k >= 20:
            from labrunner.errors import RigError

            raise RigError("CAN bus off")
        return super()._step(u)
