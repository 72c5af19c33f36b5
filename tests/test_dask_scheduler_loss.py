"""Issue 36: a Dask scheduler killed during a campaign stops it in one line (the probe finds the
loss; distributed's reconnection tracebacks are held back), never a 30-line traceback."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_campaign_support import ROOT, campaign_text, ledger_rows, wait_for, write

DASK = Path(sys.executable).with_name("dask")


def _spawn(args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([str(DASK), *args], stdout=log.open("w"), stderr=subprocess.STDOUT, env=env)


@pytest.mark.slow
def test_a_killed_dask_scheduler_stops_the_campaign_in_one_line(project):
    if not DASK.exists():
        pytest.fail("the dask command (distributed) is missing beside this Python")
    log = project / "scheduler.log"
    scheduler = _spawn(["scheduler", "--port", "0", "--no-dashboard"], log)
    worker = None
    try:
        assert wait_for(lambda: re.search(r"tcp://[0-9.]+:\d+", log.read_text()), timeout=60.0), log.read_text()
        address = re.search(r"tcp://[0-9.]+:\d+", log.read_text()).group(0)
        worker = _spawn(["worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"], project / "w.log")
        grid = '"controller.k_p" = { values = [1.0, 2.0, 3.0, 4.0] }'
        path = write(project / "c.toml", campaign_text("c", grid=grid, duration=60.0))
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        run = subprocess.Popen(
            [sys.executable, "-m", "labrunner", "run", str(path), "--executor", address, "--batch-size", "1"],
            cwd=project,
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert wait_for(lambda: (project / "data" / "c" / "ledger.sqlite").exists(), timeout=90.0)
        time.sleep(3.0)  # a batch running on the worker
        scheduler.send_signal(signal.SIGKILL)
        _, err = run.communicate(timeout=120)
    finally:
        for proc in (scheduler, worker):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert run.returncode == 1, err
    assert "Traceback" not in err and "ERROR" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("labrunner run: error: stopped: lost the connection to the Dask scheduler at"), err
    assert "labrunner resume" in last
    assert {r["state"] for r in ledger_rows(project / "data" / "c")} <= {"done", "planned", "claimed"}
