"""Issue 36 on a Dask cluster of separate processes (``dask scheduler``, ``dask worker``): a
scheduler killed during a campaign stops it in one line (the probe finds the loss; distributed's
reconnection tracebacks are held back), never a 30-line traceback; one Ctrl-C stops the batch
running on a worker at its next progress report, as on a process pool."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_campaign_support import ROOT, campaign_text, ledger_rows, spawn, wait_for, write

DASK = Path(sys.executable).with_name("dask")


def _spawn(args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([str(DASK), *args], stdout=log.open("w"), stderr=subprocess.STDOUT, env=env)


@pytest.mark.slow
def test_a_killed_dask_scheduler_stops_the_campaign_in_one_line(project):
    with _cluster(project) as (address, scheduler, _):
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
    assert run.returncode == 1, err
    assert "Traceback" not in err and "ERROR" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("labrunner run: error: stopped: lost the connection to the Dask scheduler at"), err
    assert "labrunner resume" in last
    assert {r["state"] for r in ledger_rows(project / "data" / "c")} <= {"done", "planned", "claimed"}


@contextlib.contextmanager
def _cluster(project: Path):
    """A scheduler and one single-threaded worker (no nanny: the worker is the process started),
    each its own process; yields the address, the scheduler's process and the worker's."""
    if not DASK.exists():
        pytest.fail("the dask command (distributed) is missing beside this Python")
    log = project / "scheduler.log"
    procs = [_spawn(["scheduler", "--port", "0", "--no-dashboard"], log)]
    try:
        assert wait_for(lambda: re.search(r"tcp://[0-9.]+:\d+", log.read_text()), timeout=60.0), log.read_text()
        address = re.search(r"tcp://[0-9.]+:\d+", log.read_text()).group(0)
        worker = ["worker", address, "--nworkers", "1", "--nthreads", "1", "--no-nanny", "--no-dashboard"]
        procs.append(_spawn(worker, project / "w.log"))
        yield address, *procs
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


@pytest.mark.slow
def test_one_ctrl_c_stops_the_batch_running_on_a_dask_worker(project):
    """Batches of 8 runs of 300 s at 200 Hz (480 000 lockstep ticks, tens of seconds of a core):
    before, the running batch finished and was committed (its 8 points done); now it stops at its
    next report, nothing published, every point planned."""
    grid = '"controller.gamma" = { log10 = [1.5, 3.0], num = 4 }\n"controller.k_p" = { log10 = [0.0, 2.0], num = 4 }'
    with _cluster(project) as (address, _, worker):
        write(project / "c.toml", campaign_text("c", grid=grid, duration=300.0))
        proc = spawn("run", "c.toml", "--executor", address, "--batch-size", "8", cwd=project)
        directory = project / "data" / "c"
        try:
            claimed = wait_for(lambda: any(r["state"] == "claimed" for r in ledger_rows(directory)), 90)
            assert claimed, proc.communicate(timeout=5)
            time.sleep(2.0)  # the worker takes the first batch and runs
            running_s = _cpu_s(worker, over_s=2.0)
            os.killpg(proc.pid, signal.SIGINT)
            pressed = time.monotonic()
            _, err = proc.communicate(timeout=60)
            took = time.monotonic() - pressed
            after_s = _cpu_s(worker, over_s=2.0)  # the worker's thread: stopped, not running on unseen
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    stopped = re.search(r"interrupted: stopping the (\d+) run\(s\) in flight now", err)
    assert stopped and int(stopped.group(1)) == 8, err  # the worker had taken a batch when the press came
    rows = ledger_rows(directory)
    assert [r["state"] for r in rows] == ["planned"] * 16, err  # the running batch did not run on
    assert all(r["attempts"] == 0 for r in rows) and not list((directory / "runs").iterdir())
    assert "16 of 16 points left" in err.strip().splitlines()[-1]
    print(f"press to exit: {took:.1f} s; worker CPU over 2 s: {running_s:.2f} s running, {after_s:.2f} s after")
    assert running_s > 0.2 and after_s < 0.25 * running_s, (running_s, after_s)


def _cpu_s(proc: subprocess.Popen, over_s: float) -> float:
    """CPU seconds (user + system) that ``proc`` uses over the next ``over_s`` seconds of wall time."""

    def used() -> float:
        fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    start = used()
    time.sleep(over_s)
    return used() - start
