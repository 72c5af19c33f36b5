"""Issue 36: a log is checked before it is believed. A damaged data chunk is ``damaged`` in the
table and metrics.csv, and ``run(id)`` / ``signals()`` refuse it (or serve it on request, saying
why) instead of 0 rows or silent padding; a swapped log is refused by ``run(id)`` and
``signals()``; one flipped bit in a log's metadata (a parameter, the config, the status, a
metric) makes it disagree with its ledger row, and that is reported; a parameter edited in the
ledger is caught; a chunk index claiming 1.5 GB allocates no more than the file holds; and
``repair`` without --force calls no campaign sound whose logs are truncated, zeroed or swapped."""

from __future__ import annotations

import csv
import shutil
import sqlite3
import struct
import tracemalloc
from pathlib import Path

import pytest
from mcap.reader import make_reader
from test_campaign_support import MOTOR_RIG, campaign_text, write

from labrunner.campaign.integrity import LedgerDamaged
from labrunner.cli import main
from labrunner.logs import read_run
from labrunner.results import open_campaign
from labrunner.run_identity import ForeignLog, UntrustedLog

GRID = '"controller.k_p" = { values = [1.0, 10.0] }'


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("trust")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (root / "rigs").mkdir()
    (root / "rigs" / "motor.toml").write_text(MOTOR_RIG)
    path = write(root / "t.toml", campaign_text("t", grid=GRID, duration=0.5))
    assert main(["run", str(path), "--out", str(root / "done"), "--workers", "1"]) == 0
    return root / "done"


@pytest.fixture
def campaign(finished: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "c"
    shutil.copytree(finished, copy)
    return copy


def _log_of(campaign: Path, k_p: float) -> tuple[str, Path]:
    table = open_campaign(campaign).table()
    point = table.loc[table["controller.k_p"] == k_p, "id"].iloc[0]
    return point, campaign / "runs" / f"{point}.mcap"


def _chunks(path: Path) -> list[tuple[int, int]]:
    with open(path, "rb") as f:
        return [(c.chunk_start_offset, c.chunk_length) for c in make_reader(f).get_summary().chunk_indexes]


def _zero_inside_the_data_chunk(path: Path) -> None:
    offset, length = _chunks(path)[0]
    data = bytearray(path.read_bytes())
    data[offset + length // 2 : offset + length // 2 + 16] = bytes(16)
    path.write_bytes(bytes(data))


def _flip(path: Path, anchor: bytes, skip: int, bit: int = 1) -> None:
    """Flip one bit of the byte ``skip`` bytes after the single occurrence of ``anchor``."""
    data = bytearray(path.read_bytes())
    assert data.count(anchor) == 1, anchor
    data[data.index(anchor) + skip] ^= 1 << bit
    path.write_bytes(bytes(data))


def _states(campaign: Path) -> dict[str, str]:
    with open(campaign / "report" / "metrics.csv", newline="") as fh:
        return {r["id"]: r["log_state"] for r in csv.DictReader(fh)}


def test_a_damaged_data_chunk_is_damaged_everywhere_and_never_served_as_0_rows(campaign):
    point, log = _log_of(campaign, 1.0)
    _zero_inside_the_data_chunk(log)
    results = open_campaign(campaign)
    table = results.table().set_index("id")
    assert table.loc[point, "log_state"] == "damaged"
    assert {p["kind"] for p in results.problems} == {"damaged"}
    with pytest.raises(UntrustedLog, match="damaged: 1 of 1 data chunks unreadable"):
        results.run(point).signals  # noqa: B018
    with pytest.raises(UntrustedLog, match="damaged"):
        results.signals()
    served = results.run(point, check=False)
    assert served.problem.startswith("damaged") and len(served.signals) == 0
    both = results.signals(check=False)
    assert both["problem"].sel(point=point).item().startswith("damaged")
    assert main(["analyse", str(campaign)]) == 0
    assert _states(campaign)[point] == "damaged"


def test_a_swapped_log_is_refused_by_run_and_signals(campaign):
    a, log_a = _log_of(campaign, 1.0)
    b, log_b = _log_of(campaign, 10.0)
    log_a.rename(log_a.with_suffix(".x"))
    log_b.rename(log_a)
    log_a.with_suffix(".x").rename(log_b)
    results = open_campaign(campaign)
    assert set(results.table()["log_state"]) == {"foreign"}
    with pytest.raises(ForeignLog, match=f"point {a}: the log is point {b}'s run"):
        results.run(a).signals  # noqa: B018
    with pytest.raises(ForeignLog):
        results.signals()
    assert results.run(a, check=False).parameters == {"controller.k_p": 10.0}


@pytest.mark.parametrize(
    "where, anchor, skip",
    [
        ("the parameters record", b"controller.k_p\x03\x00\x00\x001.0", 18),  # 1.0 -> 3.0
        ("the config record", b'"k_p": 1.0}', 7),  # 1.0 -> 3.0
        ("the outcome's status", b"status\t\x00\x00\x00completed", 10),  # completed -> aompleted
        ("a metric", b"rms_error\x11\x00\x00\x00", 13),  # its first digit, one bit off
    ],
)
def test_one_flipped_bit_in_a_logs_metadata_is_caught(campaign, where, anchor, skip):
    point, log = _log_of(campaign, 1.0)
    before = read_run(log)
    _flip(log, anchor, skip)
    assert read_run(log).metadata != before.metadata or read_run(log).outcome != before.outcome  # it took
    results = open_campaign(campaign)
    assert results.table().set_index("id").loc[point, "log_state"] == "disagrees", where
    with pytest.raises(UntrustedLog, match="disagrees with the ledger"):
        results.run(point).outcome  # noqa: B018
    assert main(["analyse", str(campaign)]) == 0
    assert _states(campaign)[point] == "disagrees"


def test_parameters_made_no_json_object_with_forged_checksums_are_named_by_table_and_analyse(campaign):
    """The table checks the ids and parameters over the rows it reads (one pass); a row it cannot read,
    although the checksums were forged to match, is still named as the ledger's damage."""
    from labrunner.campaign import integrity

    point, _ = _log_of(campaign, 1.0)
    db = sqlite3.connect(campaign / "ledger.sqlite")
    db.execute("UPDATE points SET parameters = '[1, 2]' WHERE id = ?", (point,))
    db.execute("UPDATE meta SET value = ? WHERE key = 'points_checksum'", (integrity.points_checksum(db),))
    db.commit()
    db.close()
    with pytest.raises(LedgerDamaged, match=r"seq \d+\) whose parameters are not a JSON object"):
        open_campaign(campaign).table()
    assert main(["analyse", str(campaign)]) == 2


def test_a_parameter_edited_in_the_ledger_is_reported(campaign):
    point, _ = _log_of(campaign, 1.0)
    db = sqlite3.connect(campaign / "ledger.sqlite")
    db.execute("UPDATE points SET parameters = ? WHERE id = ?", ('{"controller.k_p": 2.0}', point))
    db.commit()
    db.close()
    with pytest.raises(LedgerDamaged, match="parameters changed since they were planned"):
        open_campaign(campaign).table()
    db = sqlite3.connect(campaign / "ledger.sqlite")  # as a ledger written before the checksum was kept
    db.execute("DELETE FROM meta WHERE key = 'points_checksum'")
    db.commit()
    db.close()
    with pytest.raises(UntrustedLog, match="controller.k_p is 1.0 in the log, 2.0 in the ledger"):
        open_campaign(campaign).run(point).signals  # noqa: B018


def _claim(path: Path, size: int, *, index: bool) -> None:
    """Make the chunk index (``index``) or the chunk record itself claim ``size`` uncompressed bytes."""
    data = bytearray(path.read_bytes())
    if not index:
        offset, _ = _chunks(path)[0]
        struct.pack_into("<Q", data, offset + 1 + 8 + 16, size)  # after opcode, length, start and end time
        path.write_bytes(bytes(data))
        return
    footer = len(data) - 8 - 29
    (summary_start,) = struct.unpack_from("<Q", data, footer + 9)
    struct.pack_into("<I", data, footer + 25, 0)  # the summary's CRC: 0, not checked
    pos = summary_start
    while pos < footer:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x08:  # chunk index: its uncompressed size is its last field
            struct.pack_into("<Q", data, pos + 9 + length - 8, size)
        pos += 9 + length
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("index", [True, False], ids=["chunk index", "chunk record"])
def test_a_small_log_claiming_1_5_gb_allocates_what_it_holds(campaign, index):
    _, log = _log_of(campaign, 1.0)
    _claim(log, 1_500_000_000, index=index)
    assert log.stat().st_size < 50_000
    tracemalloc.start()
    try:
        read = read_run(log)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20_000_000, peak
    if index:  # the chunk itself says its true size: read whole
        assert read.n_samples == 100 and not read.damaged
    else:
        assert "holds" in read.damaged and "not 1500000000" in read.damaged


@pytest.mark.parametrize("harm", ["truncated", "zeroed", "swapped", "chunk damaged"])
def test_repair_without_force_calls_no_campaign_with_harmed_logs_sound(campaign, capsys, harm):
    _, log = _log_of(campaign, 1.0)
    _, other = _log_of(campaign, 10.0)
    if harm == "truncated":
        with open(log, "r+b") as f:
            f.truncate(log.stat().st_size // 2)
    elif harm == "zeroed":
        log.write_bytes(bytes(log.stat().st_size))
    elif harm == "swapped":
        log.rename(log.with_suffix(".x"))
        other.rename(log)
        log.with_suffix(".x").rename(other)
    else:
        _zero_inside_the_data_chunk(log)
    code = main(["repair", str(campaign)])
    out = capsys.readouterr()
    assert code == 0 and "sound" not in out.err, out.err
    assert "unusable" in out.out or "rerun" in out.out, out.out


def test_repair_without_force_still_leaves_a_sound_campaign_alone(campaign, capsys):
    assert main(["repair", str(campaign)]) == 2
    assert "is sound" in capsys.readouterr().err
