"""The seal (labrunner.campaign.seal): a session that ends cleanly seals the campaign directory, a
resume of a sealed directory settles nothing and reads no row, and anything changed behind the
seal's back — a log deleted, a torn file dropped, a row edited — sends resume down the full path."""

from __future__ import annotations

import json
import os
import sqlite3
from pathlib import Path

import pytest
from test_campaign_support import campaign_text, ledger_rows, write

from labrunner.campaign import integrity, recovery, seal
from labrunner.campaign.ledger import TERMINAL, Ledger
from labrunner.cli import main


@pytest.fixture
def finished(project: Path) -> Path:
    """A finished 9-point campaign directory, as ``labrunner run`` leaves it."""
    path = write(project / "c.toml", campaign_text())
    assert main(["run", str(path), "--workers", "1"]) == 0
    return project / "data" / "tiny"


def _sealed(directory: Path) -> bool:
    with Ledger.open_readonly(directory, verify=False) as ledger:
        return seal.holds(ledger, ledger.counts())


def _reference(directory: Path) -> bool:
    """A plain check of what the seal claims: a stat per point, a listing for torn files."""
    rows = ledger_rows(directory)
    if any(r["state"] == "claimed" for r in rows):
        return False
    if any(name.startswith(".tmp-") for name in os.listdir(directory / "runs")):
        return False
    for r in rows:
        if r["state"] in TERMINAL and r["log_path"] and not (directory / r["log_path"]).exists():
            return False
        if r["state"] not in TERMINAL and (directory / "runs" / f"{r['id']}.mcap").exists():
            return False
    return True


def _consistent(directory: Path) -> bool:
    with Ledger.open(directory, verify=False) as ledger:
        return seal.consistent(ledger, seal.listing(ledger)[1])


def test_a_finished_run_is_sealed_and_resume_then_settles_and_reads_nothing(finished, monkeypatch):
    assert _sealed(finished)

    def refuse(*args):
        raise AssertionError("a sealed directory is not settled or read row by row")

    monkeypatch.setattr(recovery, "recover", refuse)
    monkeypatch.setattr(integrity, "ids_checksum", refuse)
    monkeypatch.setattr(seal, "consistent", refuse)
    before = ledger_rows(finished)
    assert main(["resume", str(finished)]) == 0
    assert ledger_rows(finished) == before and _sealed(finished)


def _delete_a_log(d: Path, rows: list[dict]) -> str:
    done = next(r for r in rows if r["state"] == "done")
    (d / done["log_path"]).unlink()
    return done["id"]


def _drop_a_torn_file(d: Path, rows: list[dict]) -> str:
    (d / "runs" / f".tmp-{rows[0]['id']}-1-abcd.mcap").write_bytes(b"torn")
    return rows[0]["id"]


def _claim_a_row_behind_its_back(d: Path, rows: list[dict]) -> str:
    with sqlite3.connect(d / "ledger.sqlite") as db:  # runs/ untouched: only the states' counts tell
        db.execute("UPDATE points SET state = 'claimed', outcome = NULL WHERE id = ?", (rows[1]["id"],))
    return rows[1]["id"]


@pytest.mark.parametrize("change", [_delete_a_log, _drop_a_torn_file, _claim_a_row_behind_its_back])
def test_resume_notices_a_change_behind_the_seal_and_settles_it(finished, change, capsys):
    rows = ledger_rows(finished)
    point = change(finished, rows)
    assert not _sealed(finished) and not _consistent(finished) and not _reference(finished)
    capsys.readouterr()
    assert main(["resume", str(finished), "--workers", "1"]) == 0
    settled = capsys.readouterr().err
    after = {r["id"]: r for r in ledger_rows(finished)}
    assert all(r["state"] in TERMINAL and (finished / r["log_path"]).exists() for r in after.values())
    if change is _delete_a_log:
        assert "1 missing log(s) to rerun" in settled and after[point]["attempts"] == 2  # run again
    elif change is _drop_a_torn_file:
        assert "1 file(s) quarantined" in settled and (finished / "quarantine").is_dir()
        assert after[point]["attempts"] == 1  # its finished run was kept, not run again
    else:  # the claimed row's log is published and complete: accepted, not run again
        assert "1 published run(s) accepted" in settled and after[point]["attempts"] == 1
        assert json.loads(after[point]["outcome_json"])["recovered"] is True
    assert _sealed(finished) and _reference(finished)


def test_the_seal_agrees_with_a_plain_check(finished):
    assert _consistent(finished) and _reference(finished)
    rows = ledger_rows(finished)
    with Ledger.open(finished) as ledger:  # a planned row whose published log stays in runs/ (retry)
        ledger.replan([rows[2]["id"]])
    assert not _consistent(finished) and not _reference(finished)
    (finished / rows[2]["log_path"]).unlink()
    assert _consistent(finished) and _reference(finished)
    (finished / "runs" / "notes.txt").write_text("a file of the user's")  # not a log: no matter
    assert _consistent(finished) and _reference(finished)


def test_a_change_in_the_same_timestamp_tick_as_the_seal_is_still_seen(finished, monkeypatch):
    """The seal reads runs/'s mtime, waits a tick, then lists: a log deleted in between, even on a
    clock so coarse that runs/'s mtime stays the same, is in the listing and no seal is written."""
    rows = ledger_rows(finished)
    victim = finished / next(r for r in rows if r["state"] == "done")["log_path"]
    runs = finished / "runs"
    stamp = runs.stat().st_mtime_ns

    def delete_within_the_tick(seconds: float) -> None:
        victim.unlink()
        os.utime(runs, ns=(stamp, stamp))  # the coarse clock did not move

    monkeypatch.setattr(seal.time, "sleep", delete_within_the_tick)
    with Ledger.open(finished, verify=False) as ledger:
        seal.clear(ledger)
        assert not seal.seal(ledger)
        assert ledger.meta().get(seal.META_KEY) is None


def test_a_file_system_with_coarse_timestamps_is_never_sealed(finished):
    runs = finished / "runs"
    whole_ms = runs.stat().st_mtime_ns // 1_000_000 * 1_000_000
    os.utime(runs, ns=(whole_ms, whole_ms))  # as FAT (2 s) or a millisecond file system keeps it
    with Ledger.open(finished, verify=False) as ledger:
        assert not seal.holds(ledger, ledger.counts()) and not seal.seal(ledger)


def test_a_session_that_will_change_the_directory_clears_the_seal_first(finished, monkeypatch):
    """A crash mid-session leaves no seal: the next resume settles everything."""
    from labrunner.campaign import scheduler

    seen = []
    real_run = scheduler.Scheduler.run

    def run(self):
        seen.append(self.ledger.meta().get(seal.META_KEY))
        return real_run(self)

    monkeypatch.setattr(scheduler.Scheduler, "run", run)
    rows = ledger_rows(finished)
    with Ledger.open(finished) as ledger:
        ledger.db.execute("UPDATE points SET state = 'failed', outcome = 'failed' WHERE id = ?", (rows[0]["id"],))
    assert main(["resume", str(finished), "--retry-failed", "--workers", "1"]) == 0
    assert seen == [None] and _sealed(finished)
    stored = json.loads(ledger_meta(finished)[seal.META_KEY])
    assert stored["counts"]["claimed"] == 0 and stored["runs"]["mtime_ns"] == (finished / "runs").stat().st_mtime_ns


def ledger_meta(directory: Path) -> dict[str, str]:
    with Ledger.open_readonly(directory, verify=False) as ledger:
        return ledger.meta()
