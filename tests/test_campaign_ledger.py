"""Ledger transactions, the directory lock and crash recovery, on a directory we corrupt by hand."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_campaign_support import campaign_text, ledger_rows, write

from labrunner.campaign import recovery
from labrunner.campaign.ledger import LEDGER_NAME, Ledger, RunRecord
from labrunner.campaign.lock import DirectoryLock, holder
from labrunner.campaign.progress import Progress
from labrunner.cli import main
from labrunner.errors import CampaignError


def _ledger(tmp_path: Path, n: int = 3) -> Ledger:
    return Ledger.create(tmp_path, meta={"campaign": "t"}, points=((i, f"p{i}", {"k": i}, "key") for i in range(n)))


def _record(pid: str, outcome: str = "completed") -> RunRecord:
    return RunRecord(pid, outcome, {"status": outcome}, {"rms_error": 1.0}, f"runs/{pid}.mcap", "h", 1, time.time())


def test_states_move_planned_claimed_terminal_and_never_twice(tmp_path):
    with _ledger(tmp_path) as led:
        led.claim(["p0", "p1"])
        with pytest.raises(CampaignError, match="not planned"):
            led.claim(["p1", "p2"])  # all or nothing: p2 stays planned
        assert led.counts() == {"planned": 1, "claimed": 2, "done": 0, "aborted": 0, "failed": 0}
        led.commit(_record("p0", "no-motion"))
        led.commit(_record("p1", "aborted"))
        with pytest.raises(CampaignError, match="not committed twice"):
            led.commit(_record("p1", "completed"))
        with pytest.raises(CampaignError):
            led.commit(_record("p2"))  # planned, never claimed
        rows = {r["id"]: r for r in led.rows()}
        assert (rows["p0"]["state"], rows["p0"]["outcome"]) == ("done", "no-motion")
        assert (rows["p1"]["state"], rows["p1"]["attempts"]) == ("aborted", 1)


def test_a_batch_commits_in_one_transaction_all_or_none(tmp_path):
    """A batch's runs go in together; one that is not claimed (committed before) refuses the
    whole batch, so that nothing of it is half-committed."""
    with _ledger(tmp_path) as led:
        led.claim(["p0", "p1", "p2"])
        led.commit(_record("p0"))
        with pytest.raises(CampaignError, match="p0 is not in state claimed"):
            led.commit(_record("p1", "aborted"), _record("p0"), _record("p2"))
        assert led.counts() == {"planned": 0, "claimed": 2, "done": 1, "aborted": 0, "failed": 0}
        led.commit(_record("p1", "aborted"), _record("p2"))
        assert led.counts() == {"planned": 0, "claimed": 0, "done": 2, "aborted": 1, "failed": 0}


def test_unclaim_restores_attempts(tmp_path):
    with _ledger(tmp_path) as led:
        led.claim(["p0"])
        led.unclaim(["p0"])
        row = led.rows()[0]
        assert (row["state"], row["attempts"]) == ("planned", 0)


def test_creation_is_atomic(tmp_path):
    def points():
        yield 0, "p0", {}, "k"
        raise RuntimeError("killed while planning")

    with pytest.raises(RuntimeError):
        Ledger.create(tmp_path, meta={}, points=points())
    assert not (tmp_path / LEDGER_NAME).exists()
    assert list(tmp_path.iterdir()) == []  # nor its temporary file
    (tmp_path / f".{LEDGER_NAME}.99999.tmp").write_bytes(b"left by a runner killed while planning")
    Ledger.create(tmp_path, meta={}, points=[(0, "p0", {}, "k")]).close()
    assert sorted(p.name for p in tmp_path.iterdir()) == [LEDGER_NAME]


def test_lock_refuses_second_holder_naming_host_and_pid(tmp_path):
    with DirectoryLock(tmp_path, "run"):
        with pytest.raises(CampaignError, match=rf"host {socket.gethostname()} PID {os.getpid()}"):
            DirectoryLock(tmp_path, "resume").acquire()
        assert holder(tmp_path).pid == os.getpid()
    assert holder(tmp_path) is None


def test_stale_lock_of_a_killed_process_is_taken_over(tmp_path):
    code = (
        "import sys, time; from pathlib import Path; from labrunner.campaign.lock import DirectoryLock\n"
        "DirectoryLock(Path(sys.argv[1]), 'run').acquire(); print('locked', flush=True); time.sleep(60)"
    )
    child = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    assert child.stdout.readline().strip() == "locked"
    with pytest.raises(CampaignError, match=f"PID {child.pid}"):
        DirectoryLock(tmp_path, "resume").acquire()
    child.send_signal(signal.SIGKILL)
    child.wait()
    lock = DirectoryLock(tmp_path, "resume").acquire()
    assert lock.took_over is not None and lock.took_over.pid == child.pid
    lock.release()


def test_recovery_accepts_published_quarantines_torn_and_replans(project, capsys):
    path = write(project / "c.toml", campaign_text())
    assert main(["run", str(path), "--workers", "1"]) == 0
    directory = project / "data" / "tiny"
    rows = ledger_rows(directory)
    a, b, c, d = (r["id"] for r in rows[:4])
    committed_a = json.loads(rows[0]["outcome_json"])
    with Ledger.open(directory) as led:  # rewind four rows to "claimed", as a crash would leave them
        led.db.execute(f"UPDATE points SET state='claimed', outcome=NULL WHERE id IN ('{a}','{b}','{c}','{d}')")
    # a: published log, row not committed → accepted
    # b: log torn (cut in half) → quarantined, rerun
    blob = (directory / f"runs/{b}.mcap").read_bytes()
    (directory / f"runs/{b}.mcap").write_bytes(blob[: len(blob) // 2])
    # c: no log at all → rerun;  d: its log moved to a temporary name (unpublished) → quarantined, rerun
    (directory / f"runs/{c}.mcap").unlink()
    os.replace(directory / f"runs/{d}.mcap", directory / f"runs/.tmp-{d}-123-abcd.mcap")
    # a terminal row whose log vanished → rerun
    e = rows[5]["id"]
    (directory / f"runs/{e}.mcap").unlink()
    with Ledger.open(directory) as led:
        report = recovery.recover(led)
        assert report.accepted == [a]
        assert sorted(report.replanned) == sorted([b, c, d]) and report.lost == [e]
        assert len(report.quarantined) == 2
        q = {r["point_id"]: r for r in led.quarantined()}
        assert set(q) == {b, d} and all((directory / r["moved_to"]).exists() for r in q.values())
        # the same record as the worker committed, marked as recovered from the log
        assert json.loads({r["id"]: r for r in led.rows()}[a]["outcome_json"]) == {**committed_a, "recovered": True}
    capsys.readouterr()
    assert main(["resume", str(directory), "--workers", "1"]) == 0
    final = ledger_rows(directory)
    assert all(r["state"] in ("done", "aborted", "failed") for r in final)
    assert {r["id"]: r["attempts"] for r in final}[b] == 2
    assert sorted(p.name for p in (directory / "runs").iterdir()) == sorted(f"{r['id']}.mcap" for r in final)


def test_progress_plain_lines_when_not_a_terminal(tmp_path):
    out = (tmp_path / "log.txt").open("w+")
    p = Progress("camp", 10, {"completed": 2}, stream=out, interval_s=0.0, bar=False)
    p.started_runs(3)
    p.update("no-motion")
    p.update("aborted")
    p.close()
    out.seek(0)
    lines = out.read().splitlines()
    assert lines[0].startswith("camp: 2/10 (2 completed, 0 no-motion, 0 aborted, 0 failed)")  # at once, before any run
    assert lines[-1].startswith("camp: 4/10 (2 completed, 1 no-motion, 1 aborted, 0 failed; 1 running)")
    assert "runs/s" in lines[-1] and "ETA" in lines[-1]


def test_progress_bar_on_a_terminal_shows_counts_rate_and_eta():
    import io
    import re

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    p = Progress("camp", 10, {"completed": 2}, stream=out, interval_s=0.0)  # bar chosen because the stream is a TTY
    for outcome in ("completed", "aborted", "failed"):
        p.update(outcome)
    p.tick()
    bar = out.getvalue().split("\r")[-1]
    assert re.search(r"camp: +50%.*\| 5/10 \[", bar), bar  # tqdm: label, share, bar, count
    assert (
        "run/s" in bar and "<" in bar and "3 completed, 0 no-motion, 1 aborted, 1 failed" in bar
    )  # rate, elapsed<ETA, counts
    p.close()
    assert out.getvalue().splitlines()[-1].startswith("camp: 5/10 (3 completed, 0 no-motion, 1 aborted, 1 failed)")


def test_progress_rate_of_a_slow_rig_keeps_two_digits(monkeypatch):
    import io

    from labrunner.campaign import progress

    now = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    p = Progress("rig", 10, stream=io.StringIO(), bar=False, interval_s=1e9)
    now[0] = 24.0
    p.update("completed")
    p.update("completed")  # 2 runs in 24 s: 0.083 runs/s, 8 left → 96 s
    assert "0.083 runs/s" in p.line() and "ETA 1:36" in p.line()
