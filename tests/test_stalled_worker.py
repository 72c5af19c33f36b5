"""Issue 36: a pool worker stopped with SIGSTOP is a dead worker, not a silent stall: once a
started batch's live ticks stand still for the stall limit, the campaign says so in one line and
stops as for a dead worker (running batches abandoned, their points claimed for resume, the
stopped worker killed); ``resume`` then finishes the campaign."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import pytest
from test_campaign_support import campaign_text, ledger_rows, wait_for, write

from labrunner.campaign import scheduler
from labrunner.cli import main

GRID = '"controller.k_p" = { values = [1.0, 2.0, 3.0, 4.0] }'


def _children() -> list[int]:
    pids = []
    for task in Path("/proc/self/task").iterdir():
        with open(task / "children") as fh:
            pids += [int(p) for p in fh.read().split()]
    return pids


def _stat(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return ["gone"] + ["0"] * 20


def _state(pid: int) -> str:
    return _stat(pid)[0]


def _cpu(pid: int) -> int:
    return int(_stat(pid)[11])  # utime [clock ticks]


@pytest.mark.slow
def test_a_worker_stopped_with_sigstop_stops_the_campaign_within_the_stall_limit(project, capsys, monkeypatch):
    monkeypatch.setattr(scheduler, "STALL_S", 3.0)
    path = write(project / "c.toml", campaign_text("c", grid=GRID, duration=100.0))  # 20 000 ticks a batch
    before = set(_children())
    stopped: list[int] = []

    def stop_a_worker() -> None:
        def busy() -> list[int]:  # a pool worker computing a batch: its CPU time grows over a second
            workers = set(_children()) - before
            first = {p: _cpu(p) for p in workers}
            time.sleep(1.0)
            return [p for p in workers if _cpu(p) > first[p] + 20]

        found: list[int] = []
        if wait_for(lambda: found.extend(busy()) or found, timeout=60.0):
            os.kill(found[0], signal.SIGSTOP)
            stopped.append(found[0])

    stopper = threading.Thread(target=stop_a_worker, daemon=True)
    stopper.start()
    t0 = time.monotonic()
    code = main(["run", str(path), "--workers", "2", "--batch-size", "1"])
    elapsed = time.monotonic() - t0
    stopper.join()
    err = capsys.readouterr().err
    assert stopped, "no busy worker was found to stop"
    assert code == 1, err
    assert "a worker made no progress for" in err and "stopped with SIGSTOP, or hung?" in err, err
    assert "Traceback" not in err
    assert _state(stopped[0]) in ("gone", "Z")  # killed with the pool, not left stopped
    states = {r["state"] for r in ledger_rows(project / "data" / "c")}
    assert "claimed" in states  # the abandoned batch's point, for resume to settle
    assert elapsed < 120.0
    assert main(["resume", "data/c", "--workers", "2"]) == 0
    assert {r["state"] for r in ledger_rows(project / "data" / "c")} == {"done"}
