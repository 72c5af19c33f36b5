"""Crash safety (issue 6): SIGKILL the runner at random moments, at least 10 times during one
campaign of ≥ 100 points, resuming each time. At the end every point is terminal exactly once,
every log opens and belongs to its point's last attempt, no log is missing or extra, and every
quarantined file is accounted for. The runs themselves are the real engine on the motor twin."""

from __future__ import annotations

import json
import os
import random
import signal
import time

import pytest
from test_campaign_support import campaign_text, cli, ledger_rows, spawn, wait_for, write

from labrunner.campaign import spec
from labrunner.cli import main
from labrunner.logs import read_run

TERMINAL = ("done", "aborted", "failed")
GRID = '"controller.gamma" = { log10 = [1.0, 3.0], num = 10 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 12 }'


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/stat") as fh:
                if entry.isdigit() and int(fh.read().rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(entry))
        except (OSError, ValueError, IndexError):
            continue
    return out


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _temporary(directory) -> set[str]:
    """Names of the temporary (unpublished) logs in ``runs/``."""
    try:
        return {e.name for e in os.scandir(directory / "runs") if e.name.startswith(".tmp-")}
    except FileNotFoundError:
        return set()


def _terminal(directory) -> int:
    return sum(r["state"] in TERMINAL for r in ledger_rows(directory))


@pytest.mark.slow
def test_sigkill_at_random_moments_loses_nothing_and_repeats_nothing(project):
    rng = random.Random(6)
    path = write(
        project / "crash.toml", campaign_text(name="crash", grid=GRID, duration=6.0)
    )  # long enough that 10 kills land before the 120 runs end
    planned = [p.id for p in spec.plan(spec.load(path))[0]]
    assert len(planned) == 120
    directory = project / "data" / "crash"
    kills = cycles = 0
    torn_left: set[str] = set()  # temporary logs that kills left behind: resume must quarantine each
    while kills < 10:
        cycles += 1
        assert cycles <= 40, "the campaign finished before 10 kills could land"
        command = ("resume", "data/crash") if (directory / "ledger.sqlite").exists() else ("run", "crash.toml")
        mid_write = kills % 3 == 1  # every third kill lands while a worker writes its batch's logs
        batch = rng.choice([8, 12]) if mid_write else rng.choice([1, 2, 3, 4])
        proc = spawn(*command, "--workers", "2", "--batch-size", str(batch), cwd=project)
        before = _terminal(directory)
        if mid_write:
            wait_for(lambda: proc.poll() is not None or bool(_temporary(directory)), 60, interval=0.0005)
        elif rng.random() < 0.3:  # anywhere: start-up, planning, ledger creation, recovery, running —
            # up to 1.5 s, but before a dozen more runs are committed: a session of the fast runner
            # can finish what is left of the 120 runs in well under a second
            stop_at = before + rng.randint(1, 12)
            wait_for(lambda: proc.poll() is not None or _terminal(directory) >= stop_at, rng.uniform(0.05, 1.5), 0.005)
        else:  # while runs are being committed
            target = before + rng.randint(1, 6)
            wait_for(lambda: proc.poll() is not None or _terminal(directory) >= target, 60)
            time.sleep(rng.uniform(0.0, 0.2))
        if proc.poll() is None and _terminal(directory) < len(planned):
            workers = _children(proc.pid)
            os.kill(proc.pid, signal.SIGKILL)  # the runner only: its workers must not outlive it
            kills += 1
            proc.communicate(timeout=60)
            assert wait_for(lambda: not any(_alive(w) for w in workers), 10), "a worker outlived its runner"
            torn_left |= _temporary(directory)
        proc.communicate(timeout=60)
    final = cli("resume", "data/crash", "--workers", "2", cwd=project)
    assert final.returncode == 0, final.stderr

    rows = ledger_rows(directory)
    assert [r["id"] for r in rows] == planned  # one row per point, none added or lost
    assert {r["state"] for r in rows} <= {"done", "aborted"}
    logs = sorted(p.name for p in (directory / "runs").iterdir())
    assert logs == sorted(f"{pid}.mcap" for pid in planned)  # no temporary file, none missing or extra
    for row in rows:
        log = read_run(directory / row["log_path"])
        assert not log.torn and log.n_samples > 0
        assert log.outcome["status"] == row["outcome"]
        assert log.metadata["run"]["point_id"] == row["id"]
        assert log.metadata["run"]["attempt"] == row["attempts"]  # the log of the attempt that counted
        assert log.metadata["metrics"]["rms_error"] == pytest.approx(row["rms_error"], rel=1e-12, nan_ok=True)

    import sqlite3

    db = sqlite3.connect(directory / "ledger.sqlite")
    quarantined = db.execute("SELECT point_id, moved_to, original FROM quarantine").fetchall()
    sessions = db.execute("SELECT COUNT(*) FROM sessions").fetchone()[0]
    db.close()
    on_disk = (
        sorted(str(p.relative_to(directory)) for p in (directory / "quarantine").glob("*"))
        if (directory / "quarantine").exists()
        else []
    )
    assert sorted(m for _, m, _ in quarantined) == on_disk  # every quarantined file recorded, every record on disk
    assert {p for p, _, _ in quarantined} <= set(planned)
    assert torn_left, "no kill landed while logs were being written: the quarantine path went untested"
    assert {f"runs/{name}" for name in torn_left} <= {o for _, _, o in quarantined}  # each torn file moved aside
    attempts = {r["id"]: r["attempts"] for r in rows}
    assert all(attempts[p] >= 2 for p, _, o in quarantined if o.startswith("runs/.tmp-"))  # and its point rerun
    reruns = sum(r["attempts"] for r in rows) - len(rows)
    recovered = sum(bool(json.loads(r["outcome_json"]).get("recovered")) for r in rows)
    print(
        f"{kills} kills in {cycles} cycles ({len(torn_left)} torn logs left), {sessions} sessions, {len(quarantined)} quarantined, "
        f"{reruns} reruns, {recovered} published runs accepted on resume"
    )

    # the interrupted campaign agrees with an uninterrupted one, point by point
    assert main(["run", str(path), "--out", "reference", "--workers", "2"]) == 0
    ref = {r["id"]: r for r in ledger_rows(project / "reference")}
    for row in rows:
        assert (row["state"], row["outcome"]) == (ref[row["id"]]["state"], ref[row["id"]]["outcome"])
        assert row["rms_error"] == pytest.approx(ref[row["id"]]["rms_error"], rel=1e-9, nan_ok=True)
