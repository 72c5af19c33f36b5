"""Issue 34: ``labrunner upgrade-logs DIR`` rewrites a campaign's labrunner-3 logs (refused by
Foxglove's indexed reader) in the current layout — the same samples bit for bit, the ledger's
fingerprints following — safely: a SIGKILL anywhere loses nothing, and the next run finishes.

The old logs are written by labrunner's own writer in its labrunner-3 layout
(``LogPrefix(log_format="labrunner-3")``) through a real ``labrunner run``."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from foxglove_reader import check_log, read_with_mcap_core
from test_campaign_support import campaign_text, write

from labrunner.analysis.analyse import analyse
from labrunner.campaign.ledger import Ledger
from labrunner.campaign.lock import DirectoryLock
from labrunner.campaign.upgrade import JOURNAL_KEY
from labrunner.cli import main
from labrunner.logs import read_run, writer
from labrunner.logs.upgrade import unindexed_messages
from labrunner.run_identity import FINGERPRINT_COLUMNS, fingerprint

GRID = '"controller.k_p" = { values = [10.0, 50.0, 3000.0] }'
ROOT = Path(__file__).resolve().parents[1]


class _OldPrefix(writer.LogPrefix):
    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs, log_format="labrunner-3")


@pytest.fixture
def old_campaign(project: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[Path, dict]:
    """A motor campaign (two completed runs, one aborted) whose logs are labrunner-3, and each
    log's reading before any upgrade."""
    with monkeypatch.context() as patch:
        patch.setattr(writer, "LogPrefix", _OldPrefix)  # BatchPrefixes makes the worker's prefixes
        path = write(project / "old.toml", campaign_text("old", grid=GRID, duration=1.0))
        assert main(["run", str(path), "--workers", "1"]) == 0
    directory = project / "data" / "old"
    logs = {p.stem: read_run(p) for p in (directory / "runs").glob("*.mcap")}
    assert len(logs) == 3 and {log.outcome["status"] for log in logs.values()} == {"completed", "aborted"}
    assert all(log.metadata["run"]["log_format"] == "labrunner-3" for log in logs.values())
    return directory, logs


def _ledger_rows(directory: Path) -> dict[str, dict]:
    with Ledger.open_readonly(directory) as ledger:
        return {r["id"]: dict(r) for r in ledger.rows()}


def assert_upgraded(directory: Path, before: dict) -> None:
    """Every log in the current layout with the same samples and records, its fingerprint in the
    ledger, no temporary file or journal left."""
    rows = _ledger_rows(directory)
    for point_id, old in before.items():
        path = directory / rows[point_id]["log_path"]
        assert unindexed_messages(path) == 0
        new = read_run(path)
        assert np.array_equal(new.data.view(np.uint64), old.data.view(np.uint64)), point_id
        assert new.metadata["run"] == {**old.metadata["run"], "log_format": writer.LOG_FORMAT}
        assert (new.outcome, new.channels, new.attachments) == (old.outcome, old.channels, old.attachments)
        assert tuple(rows[point_id][c] for c in FINGERPRINT_COLUMNS) == fingerprint(path), point_id
    assert not list((directory / "runs").glob(".tmp-*"))
    with Ledger.open_readonly(directory) as ledger:
        assert JOURNAL_KEY not in ledger.meta()


@pytest.mark.slow
def test_old_logs_are_rewritten_once_and_open_in_foxglove(old_campaign, capsys):
    directory, before = old_campaign
    first = next(iter((directory / "runs").glob("*.mcap")))
    assert "chunk index without message indexes" in read_with_mcap_core(first)["indexed"]["error"]
    first.chmod(0o440)  # a log made read-only stays so
    stats = {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")}

    assert main(["upgrade-logs", str(directory), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "would rewrite 3 log(s)" in out and "0 already current" in out
    assert {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")} == stats  # nothing touched

    assert main(["upgrade-logs", str(directory)]) == 0
    captured = capsys.readouterr()
    assert "rewrote 3 log(s)" in captured.out and "3/3 logs checked, 3 rewritten" in captured.err
    assert_upgraded(directory, before)
    assert stat.S_IMODE(first.stat().st_mode) == 0o440
    for path in (directory / "runs").glob("*.mcap"):
        check_log(path)
    summary = analyse(directory, workers=1, progress=False)  # the new fingerprints vouch: no log read
    assert summary["logs_read"] == 0 and not summary["problems"]

    stats = {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")}
    assert main(["upgrade-logs", str(directory)]) == 0  # idempotent: nothing left to rewrite
    out = capsys.readouterr().out
    assert "nothing to rewrite, 3 already current" in out
    assert {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")} == stats


def test_refused_while_a_runner_holds_the_campaign(old_campaign, capsys):
    directory, _ = old_campaign
    stats = {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")}
    with DirectoryLock(directory, "run"):
        assert main(["upgrade-logs", str(directory)]) == 1
    assert "is in use by" in capsys.readouterr().err
    assert {p.name: fingerprint(p) for p in (directory / "runs").glob("*.mcap")} == stats


# Runs ``labrunner upgrade-logs DIR`` and SIGKILLs itself at the n-th call of one step.
KILLER = textwrap.dedent(
    """
    import os, signal, sys
    import labrunner.logs.upgrade as upgrade
    from labrunner.campaign.ledger import Ledger
    from labrunner.cli import main

    directory, step, nth = sys.argv[1], sys.argv[2], int(sys.argv[3])
    calls = []

    def killing(function, after):
        def wrapped(*args, **kwargs):
            calls.append(1)
            if len(calls) == nth and not after:
                os.kill(os.getpid(), signal.SIGKILL)
            result = function(*args, **kwargs)
            if len(calls) == nth and after:
                os.kill(os.getpid(), signal.SIGKILL)
            return result
        return wrapped

    if step == "rewritten":  # a temporary file written, not yet fsynced nor in the journal
        upgrade.rewrite = killing(upgrade.rewrite, after=True)
    elif step == "renaming":  # the batch in the journal, some of its files renamed
        os.replace = killing(os.replace, after=False)
    elif step == "renamed":  # every file renamed, the fingerprints not yet in the ledger
        Ledger.set_fingerprints = killing(Ledger.set_fingerprints, after=False)
    main(["upgrade-logs", directory])
    """
)


@pytest.mark.parametrize(
    "step, nth, renamed", [("rewritten", 2, 0), ("renaming", 2, 1), ("renamed", 1, 3)]
)  # renamed: logs already in the new layout when the process dies
def test_a_kill_at_any_step_loses_nothing_and_the_next_run_finishes(old_campaign, step, nth, renamed):
    directory, before = old_campaign
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, "-c", KILLER, str(directory), step, str(nth)], env=env, capture_output=True, timeout=120
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    rows = _ledger_rows(directory)
    new = [pid for pid, row in rows.items() if unindexed_messages(directory / row["log_path"]) == 0]
    assert len(new) == renamed
    for point_id, old in before.items():  # every log whole, old or new, and still its point's
        log = read_run(directory / rows[point_id]["log_path"])
        assert not log.torn and not log.damaged and log.metadata["run"]["point_id"] == point_id
        assert np.array_equal(log.data.view(np.uint64), old.data.view(np.uint64))
    with Ledger.open_readonly(directory) as ledger:
        assert (JOURNAL_KEY in ledger.meta()) == (step != "rewritten")

    assert main(["upgrade-logs", str(directory)]) == 0
    assert_upgraded(directory, before)


def test_thinned_float32_logs_are_upgraded(project):
    """Logs with both topics (``samples_hz``) and float32 fields (``precision``) keep them."""
    extra = '[logging]\nsamples_hz = 40.0\nprecision = "float32"\n'
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(writer, "LogPrefix", _OldPrefix)
        path = write(project / "thin.toml", campaign_text("thin", grid=GRID, duration=1.0, extra=extra))
        assert main(["run", str(path), "--workers", "1"]) == 0
    directory = project / "data" / "thin"
    before = {p.stem: read_run(p) for p in (directory / "runs").glob("*.mcap")}
    assert main(["upgrade-logs", str(directory)]) == 0
    assert_upgraded(directory, before)
    for path in (directory / "runs").glob("*.mcap"):
        log = check_log(path)
        assert log.metadata["run"]["samples"].startswith("every 5th") and "float32" in log.metadata["run"]["samples"]


def test_a_streamed_log_keeps_its_chunks_as_they_were(tmp_path):
    """A real rig's log (a chunk per flush) is rewritten chunk for chunk: the compressed bytes are
    copied, not compressed again, and each chunk gets its index."""
    from mcap.reader import make_reader

    from labrunner.logs import RunLogWriter
    from labrunner.logs.upgrade import rewrite, same_run

    old, new = tmp_path / "old.mcap", tmp_path / "new.mcap"
    prefix = writer.LogPrefix(fs=500.0, channels=["y", "u"], log_format="labrunner-3")
    k = np.arange(2000.0)
    with RunLogWriter(old, metadata={"run": {"point_id": "p"}}, prefix=prefix, flush_interval_s=0.0) as w:
        for start in range(0, 2000, 300):
            w.write_block(start, {"y": np.sin(k[start : start + 300]), "u": -k[start : start + 300]})
        w.finish({"status": "completed"})
    with open(new, "wb") as fh:
        rewrite(old, fh)
    same_run(read_run(old), new)

    def chunks(path: Path) -> list[tuple[bytes, int]]:
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
            out = []
            for index in summary.chunk_indexes:
                f.seek(index.chunk_start_offset)
                record = f.read(index.chunk_length)
                out.append((record[-index.compressed_size :], index.message_index_length))
            return out

    before, after = chunks(old), chunks(new)
    assert len(before) == 7 and [c for c, _ in after] == [c for c, _ in before]
    assert all(n == 0 for _, n in before) and all(n > 0 for _, n in after)
    check_log(new)


def test_a_log_that_cannot_be_read_or_is_missing_is_left_as_it_is_and_named(old_campaign, capsys):
    directory, before = old_campaign
    torn, gone, _ = sorted((directory / "runs").glob("*.mcap"))
    with open(torn, "r+b") as f:
        f.truncate(torn.stat().st_size - 8)
    damaged = torn.read_bytes()
    gone.unlink()
    assert main(["upgrade-logs", str(directory)]) == 1
    out = capsys.readouterr().out
    assert "rewrote 1 log(s)" in out and f"skipped {torn.stem}: runs/{torn.name}" in out
    assert f"skipped {gone.stem}: runs/{gone.name}: missing" in out
    assert torn.read_bytes() == damaged and not gone.exists()
    del before[torn.stem], before[gone.stem]
    rows = _ledger_rows(directory)
    for point_id in before:
        assert unindexed_messages(directory / rows[point_id]["log_path"]) == 0


def test_a_directory_without_a_ledger_is_refused_in_one_line(tmp_path, capsys):
    for extra in ([], ["--dry-run"]):
        assert main(["upgrade-logs", str(tmp_path), *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert "holds no campaign ledger" in err and len(err.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []  # no lock file made
