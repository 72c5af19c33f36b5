"""Issue 18, ledger integrity: damage is noticed and named; ``labrunner repair`` rebuilds a damaged or
deleted ledger from the campaign copy and the published logs, equal to the original on every
published point; a log damaged in the middle is reported as damaged, with what could be read."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3

import pytest
from test_campaign_support import campaign_text, ledger_rows, write

from labrunner.cli import main
from labrunner.logs import read_run

# what a rebuilt ledger cannot know: when the parent claimed and committed, and its timings
LOCAL = ("claimed_at", "finished_at", "engine_s", "write_s", "publish_s")


@pytest.fixture
def finished(project):
    grid = '"controller.gamma" = { log10 = [1.5, 3.0], num = 4 }\n"controller.k_p" = { log10 = [0.0, 2.0], num = 3 }'
    path = write(project / "r.toml", campaign_text(name="r", grid=grid, duration=1.0))
    assert main(["run", str(path), "--workers", "2"]) == 0
    return project / "data" / "r"


def _published(rows: list[dict]) -> dict[str, dict]:
    return {r["id"]: {k: v for k, v in r.items() if k not in LOCAL} for r in rows if r["log_path"]}


@pytest.mark.parametrize("damage", ["deleted", "garbage", "truncated", "rows-deleted"])
def test_a_rebuilt_ledger_equals_the_original_on_every_published_point(finished, capsys, damage):
    original = ledger_rows(finished)
    assert len(original) == 12
    ledger = finished / "ledger.sqlite"
    if damage == "deleted":
        ledger.unlink()
    elif damage == "garbage":
        ledger.write_bytes(os.urandom(ledger.stat().st_size))
    elif damage == "truncated":
        ledger.write_bytes(ledger.read_bytes()[:4096])
    else:
        db = sqlite3.connect(ledger)
        db.execute("DELETE FROM points WHERE seq IN (2, 5)")
        db.commit()
        db.close()
        capsys.readouterr()
        assert main(["status", str(finished)]) == 2
        assert "holds 10 point rows of the 12 planned, 2 deleted" in capsys.readouterr().err
    capsys.readouterr()
    assert main(["repair", str(finished)]) == 0
    out = capsys.readouterr().out
    assert "12 published run(s) restored from their logs" in out and "0 to run" in out
    rebuilt = ledger_rows(finished)
    assert _published(rebuilt) == _published(original)
    if damage != "deleted":  # the old file is kept, never deleted
        kept = list((finished / "quarantine").glob("ledger.sqlite.*"))
        assert kept and not any(p.name.endswith(("-wal", "-shm")) for p in kept[:1])
    assert main(["resume", str(finished)]) == 0  # nothing left to run, nothing runs twice
    assert all(r["attempts"] == 1 for r in ledger_rows(finished))
    assert main(["status", str(finished), "--json"]) == 0


def test_repair_keeps_failed_points_and_reruns_what_has_no_log(finished, capsys):
    db = sqlite3.connect(finished / "ledger.sqlite")
    first, second = (r[0] for r in db.execute("SELECT id FROM points ORDER BY seq LIMIT 2"))
    db.execute(
        "UPDATE points SET state = 'failed', outcome = 'failed', outcome_json = ?, log_path = NULL WHERE id = ?",
        (json.dumps({"status": "failed", "message": "boom"}), first),
    )
    db.commit()
    db.close()
    os.unlink(finished / "runs" / f"{first}.mcap")
    os.unlink(finished / "runs" / f"{second}.mcap")  # a published log lost as well: that point reruns
    assert main(["repair", str(finished)]) == 0
    assert "1 failed point(s) kept from the old ledger" in capsys.readouterr().out
    rows = {r["id"]: r for r in ledger_rows(finished)}
    assert rows[first]["state"] == "failed" and json.loads(rows[first]["outcome_json"])["message"] == "boom"
    assert rows[second]["state"] == "planned"
    assert main(["resume", str(finished)]) == 0
    assert ledger_rows(finished)[1]["state"] in ("done", "aborted")


def test_resume_notices_a_ledger_that_no_longer_holds_the_stored_campaign(finished, capsys):
    db = sqlite3.connect(finished / "ledger.sqlite")
    db.execute("UPDATE points SET id = 'ffffffffffffffff' WHERE seq = 3")
    db.execute("DELETE FROM meta WHERE key = 'ids_checksum'")  # as an older ledger, checked by re-planning
    db.commit()
    db.close()
    assert main(["resume", str(finished)]) == 2
    err = capsys.readouterr().err
    assert "does not hold the stored campaign's points (1 planned point(s) missing, 1 foreign" in err
    assert err.count("\n") == 1 and f"labrunner repair {finished}" in err


def test_a_log_damaged_in_the_middle_is_damaged_not_torn(finished, capsys):
    from mcap.reader import make_reader

    log = sorted((finished / "runs").glob("*.mcap"))[0]
    copy = finished.parent / "damaged.mcap"
    shutil.copy(log, copy)
    with open(copy, "rb") as fh:
        summary = make_reader(fh).get_summary()
    chunk = summary.chunk_indexes[0]  # the signals: /run/samples, each sample once
    with open(copy, "r+b") as fh:  # 64 bytes in the middle of the signal chunk's compressed records
        fh.seek(chunk.chunk_start_offset + chunk.chunk_length // 2)
        fh.write(b"\xa5" * 64)
    good, bad = read_run(log), read_run(copy)
    assert not bad.torn and bad.damaged.startswith("1 of ") and "unreadable" in bad.damaged
    assert bad.outcome == good.outcome and bad.metadata["run"] == good.metadata["run"]  # the summary is intact
    capsys.readouterr()
    assert main(["inspect", str(copy)]) == 0
    head = capsys.readouterr().out.splitlines()[:2]
    assert "[DAMAGED: 1 of" in head[0] and "TORN" not in head[0]
    assert head[1].startswith(f"outcome     {good.outcome['status']}")


def test_an_unexpected_error_is_one_line_naming_the_traceback_file(monkeypatch, capsys):
    from labrunner.cli import status_cmd

    def bug(args):
        raise RuntimeError("an invariant\nthat broke")

    monkeypatch.setattr(status_cmd, "run", bug)  # registered as the command's func when main() builds its parser
    assert main(["status", "anything"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error: RuntimeError: an invariant that broke; traceback in " in err
    path = err.rstrip("\n").rsplit("traceback in ", 1)[1]
    text = open(path, encoding="utf-8").read()
    assert "Traceback (most recent call last)" in text and "an invariant" in text and "status anything" in text
    os.unlink(path)


def test_status_checks_the_structure_and_resume_every_row(finished, capsys, monkeypatch):
    """``status`` (sub-second at 10^6 points) counts from covering indexes and, above
    FULL_CHECK_POINTS points, checks structure, count and grid order only; the checks that read
    every row (ids' checksum) stay resume's."""
    from labrunner.campaign import status

    monkeypatch.setattr(status, "FULL_CHECK_POINTS", 5)  # this campaign's 12 points count as many
    copy = finished.parent / "ids-changed"
    shutil.copytree(finished, copy)
    db = sqlite3.connect(copy / "ledger.sqlite")
    db.execute("UPDATE points SET id = 'ffffffffffffffff' WHERE seq = 3")
    db.commit()
    plans = [
        db.execute(f"EXPLAIN QUERY PLAN {q}").fetchall()[0][3]
        for q in (
            "SELECT COALESCE(outcome, state), COUNT(*) FROM points GROUP BY COALESCE(outcome, state)",
            "SELECT COUNT(*) FROM points WHERE finished_at IS NOT NULL",
        )
    ]
    db.close()
    assert all("COVERING INDEX" in plan for plan in plans), plans
    capsys.readouterr()
    assert main(["status", str(copy)]) == 0
    assert main(["resume", str(copy)]) == 2
    assert "their ids changed" in capsys.readouterr().err
    monkeypatch.setattr(status, "FULL_CHECK_POINTS", 20_000)
    assert main(["status", str(copy)]) == 2  # a small campaign: every check
    assert "their ids changed" in capsys.readouterr().err
