"""Issue 26: the ledger records each published log's fingerprint (size, mtime, ctime, inode), by
which ``analyse`` proves a log unchanged without reading it; a log swapped, copied or edited since
gets another fingerprint and is read (and found foreign), and ledgers without fingerprints (older
ones) still have every log read."""

from __future__ import annotations

import csv
import os
import shutil
import sqlite3
from pathlib import Path

import pytest
from test_campaign_support import campaign_text, write

from labrunner.analysis import log_checks, table
from labrunner.analysis.analyse import analyse
from labrunner.campaign.ledger import Ledger
from labrunner.cli import main
from labrunner.run_identity import FINGERPRINT_COLUMNS, fingerprint

GRID = '"controller.k_p" = { values = [10.0, 50.0, 90.0] }'


@pytest.fixture
def campaign(project: Path) -> Path:
    path = write(project / "fp.toml", campaign_text("fp", grid=GRID, duration=1.0))
    assert main(["run", str(path), "--workers", "1"]) == 0
    return project / "data" / "fp"


@pytest.fixture
def metadata_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The logs whose metadata ``analyse`` reads to prove their point (workers=1: in this process)."""
    seen: list[str] = []
    original = table.named_point

    def counted(path: str):
        seen.append(Path(path).name)
        return original(path)

    monkeypatch.setattr(table, "named_point", counted)
    return seen


def _rows(directory: Path) -> dict[str, dict]:
    with Ledger.open_readonly(directory) as ledger:
        return {r["id"]: dict(r) for r in ledger.rows()}


def _states(directory: Path) -> dict[str, str]:
    with open(directory / "report" / "metrics.csv", newline="") as fh:
        return {r["id"]: r["log_state"] for r in csv.DictReader(fh)}


def _recorded(row: dict) -> tuple:
    return tuple(row[c] for c in FINGERPRINT_COLUMNS)


def test_the_worker_records_each_published_logs_fingerprint(campaign):
    rows = _rows(campaign)
    assert len(rows) == 3
    for pid, row in rows.items():
        assert _recorded(row) == fingerprint(campaign / row["log_path"]), pid


def test_a_first_analyse_reads_no_log_whose_fingerprint_matches(campaign, metadata_reads):
    summary = analyse(campaign, workers=1, progress=False)
    assert metadata_reads == [] and summary["logs_read"] == 0 and not summary["problems"]
    assert set(_states(campaign).values()) == {"ok"}


@pytest.fixture
def logs_opened(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The logs the checks open to look for the MCAP magic at both ends."""
    seen: list[str] = []

    def counted(path, *args, **kwargs):
        seen.append(Path(path).name)
        return open(path, *args, **kwargs)

    monkeypatch.setattr(log_checks, "open", counted, raising=False)
    return seen


def test_a_log_whose_fingerprint_matches_is_not_even_opened(campaign, logs_opened):
    analyse(campaign, workers=1, progress=False)  # one stat each: its two reads were a disk read each
    assert logs_opened == [] and set(_states(campaign).values()) == {"ok"}


def test_a_log_cut_short_after_its_commit_is_opened_and_found_torn(campaign, metadata_reads, logs_opened):
    a = sorted((campaign / "runs").glob("*.mcap"))[0]
    with open(a, "r+b") as f:
        f.truncate(a.stat().st_size - 8)  # its closing magic gone: another size, another fingerprint
    summary = analyse(campaign, workers=1, progress=False)
    assert logs_opened == [a.name] and metadata_reads == []  # a torn log is read whole (salvaged), not only named
    assert _states(campaign)[a.stem] == "torn" and {p["kind"] for p in summary["problems"]} == {"torn"}


def test_logs_swapped_between_points_before_the_first_analyse_are_foreign(campaign, metadata_reads):
    a, b = sorted((campaign / "runs").glob("*.mcap"))[:2]
    a.rename(a.with_suffix(".tmp"))  # mv keeps each file's mtime: each path now has the other's
    b.rename(a)
    a.with_suffix(".tmp").rename(b)
    summary = analyse(campaign, workers=1, progress=False)
    assert sorted(metadata_reads) == sorted([a.name, b.name])  # only the two whose fingerprint changed
    states = _states(campaign)
    assert states[a.stem] == states[b.stem] == "foreign" and list(states.values()).count("ok") == 1
    assert {p["kind"] for p in summary["problems"]} == {"foreign"}


def test_a_copy_with_its_mtime_set_back_is_read_and_foreign(campaign, metadata_reads):
    a, b = sorted((campaign / "runs").glob("*.mcap"))[:2]
    mtime = a.stat().st_mtime_ns
    shutil.copyfile(b, a)  # in place: the same inode
    os.utime(a, ns=(mtime, mtime))  # and the old mtime: only the size and the ctime tell
    analyse(campaign, workers=1, progress=False)
    assert metadata_reads == [a.name] and _states(campaign)[a.stem] == "foreign"


def test_an_edit_that_keeps_size_and_mtime_is_read_again(campaign, metadata_reads):
    a = sorted((campaign / "runs").glob("*.mcap"))[0]
    st = a.stat()
    a.write_bytes(a.read_bytes())  # the same bytes, a new ctime: the fingerprint no longer vouches
    os.utime(a, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert a.stat().st_size == st.st_size and a.stat().st_mtime_ns == st.st_mtime_ns
    analyse(campaign, workers=1, progress=False)
    assert metadata_reads == [a.name] and _states(campaign)[a.stem] == "ok"


def test_a_ledger_without_fingerprints_reads_every_log_once(campaign, metadata_reads):
    with Ledger.open(campaign) as ledger:  # as a ledger written before the columns existed
        for column in FINGERPRINT_COLUMNS:
            ledger.db.execute(f"ALTER TABLE points DROP COLUMN {column}")
    analyse(campaign, workers=1, progress=False)
    assert len(metadata_reads) == 3
    analyse(campaign, workers=1, progress=False)  # then the report's table vouches for them
    assert len(metadata_reads) == 3 and set(_states(campaign).values()) == {"ok"}


def test_opening_an_old_ledger_for_writing_adds_the_columns_and_replan_clears_them(campaign):
    db = sqlite3.connect(campaign / "ledger.sqlite")
    for column in FINGERPRINT_COLUMNS:
        db.execute(f"ALTER TABLE points DROP COLUMN {column}")
    db.close()
    with Ledger.open(campaign) as ledger:
        columns = {r[1] for r in ledger.db.execute("PRAGMA table_info(points)")}
        assert set(FINGERPRINT_COLUMNS) <= columns
        first = ledger.rows()[0]["id"]
        ledger.db.execute("UPDATE points SET log_size = 1, log_mtime_ns = 2, log_ctime_ns = 3, log_inode = 4")
        ledger.replan([first])
    assert _recorded(_rows(campaign)[first]) == (None, None, None, None)


def test_repair_records_the_fingerprint_of_every_log_it_restores(campaign, metadata_reads):
    (campaign / "ledger.sqlite").unlink()
    assert main(["repair", str(campaign)]) == 0
    rows = _rows(campaign)
    assert all(_recorded(r) == fingerprint(campaign / r["log_path"]) for r in rows.values())
    analyse(campaign, workers=1, progress=False)
    assert metadata_reads == [] and set(_states(campaign).values()) == {"ok"}
