"""``labrunner upgrade-logs DIR``: rewrite a campaign's ``labrunner-3`` logs so that Foxglove opens them.

Each finished point's log whose chunks lack message indexes (:func:`~labrunner.logs.upgrade.
unindexed_messages`) is rewritten by :func:`~labrunner.logs.upgrade.rewrite` beside itself, as
``runs/.tmp-<id>-upgrade.mcap``, fsynced and read back (:func:`~labrunner.logs.upgrade.same_run`:
the same samples bit for bit, the same records). Then, a batch of logs at a time:

1. the ledger's ``meta`` records the batch (``logs_upgrading``: point id → log and temporary
   file), in one transaction;
2. each temporary file is renamed over its log (atomic), and ``runs/`` is fsynced;
3. one transaction records the new logs' fingerprints and removes the batch's entry.

A crash anywhere leaves every log whole — the old file or its rewrite, never half of one — and a
ledger that says which: before step 1 the batch's temporary files are leftovers, removed by the
next ``upgrade-logs`` (or quarantined by ``resume``); after it, the next ``upgrade-logs`` first
finishes the batch (renames what is left, records the fingerprints), then goes on. Between 2 and
3 a rewritten log's fingerprint differs from the ledger's, which only makes ``analyse`` read it.

The command holds the campaign directory's lock (refused while a runner holds it), clears the
seal first and seals the directory again at the end when it is consistent; a second run rewrites
nothing. ``--dry-run`` only reads: what would be rewritten and about how many bytes it adds.
"""

from __future__ import annotations

import json
import os
import stat
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from labrunner.campaign import seal
from labrunner.campaign.ledger import TERMINAL, Ledger, fsync_dir, ledger_path
from labrunner.campaign.lock import DirectoryLock
from labrunner.campaign.recovery import verify_log
from labrunner.campaign.worker import TMP_PREFIX
from labrunner.run_identity import fingerprint

if TYPE_CHECKING:  # the log reader is imported where logs are read: `labrunner --help` stays light
    from labrunner.logs import RunLog

#: The ledger ``meta`` key of the batch being renamed (JSON: point id → [log path, temporary file name]).
JOURNAL_KEY = "logs_upgrading"
BATCH = 64  # logs renamed per ledger transaction
_SUFFIX = "-upgrade.mcap"
_INDEX_BYTES = 16  # a message index entry: log time and offset (u64 each), uncompressed


@dataclass
class UpgradeReport:
    """What :func:`upgrade_logs` did (or, dry, would do)."""

    dry_run: bool = False
    rewritten: int = 0
    current: int = 0
    finished: int = 0  # logs of a batch an earlier, interrupted run had journaled
    skipped: list[str] = field(default_factory=list)  # "<id>: why"
    bytes_before: int = 0
    bytes_after: int = 0  # dry: estimated (16 bytes a message no index lists)
    seconds: float = 0.0

    def describe(self) -> str:
        verb = "would rewrite" if self.dry_run else "rewrote"
        growth = self.bytes_after - self.bytes_before
        about = "about " if self.dry_run else ""
        parts = [
            f"{verb} {self.rewritten} log(s) in the current layout "
            f"({_mb(self.bytes_before)} → {about}{_mb(self.bytes_after)}, {about}+{_mb(growth)})"
            if self.rewritten
            else f"nothing to rewrite{' now' if self.dry_run else ''}",
            f"{self.current} already current",
        ]
        if self.finished:
            parts.append(f"finished {self.finished} of an interrupted run")
        if self.skipped:
            parts.append(f"{len(self.skipped)} skipped")
        if not self.dry_run:
            parts.append(f"{self.seconds:.1f} s")
        return ", ".join(parts)


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def _logs(ledger: Ledger) -> list[tuple[str, str]]:
    """(point id, log path) of every finished point that has a log, in grid order."""
    marks = ",".join("?" * len(TERMINAL))
    rows = ledger.db.execute(
        f"SELECT id, log_path FROM points WHERE state IN ({marks}) AND log_path IS NOT NULL ORDER BY seq", TERMINAL
    )
    return [(pid, log_path) for pid, log_path in rows]


def _batches(items: list, size: int) -> Iterator[list]:
    for start in range(0, len(items), size):
        yield items[start : start + size]


def dry_run(directory: Path) -> UpgradeReport:
    """What :func:`upgrade_logs` would rewrite, reading the ledger and the logs' summaries only."""
    from labrunner.logs.upgrade import unindexed_messages

    report = UpgradeReport(dry_run=True)
    with Ledger.open_readonly(directory) as ledger:
        pending = json.loads(ledger.meta().get(JOURNAL_KEY) or "{}")
        report.finished = len(pending)
        for point_id, log_path in _logs(ledger):
            path = directory / log_path
            try:
                n = unindexed_messages(path)
            except Exception as exc:  # any unreadable log is reported, whatever the reader raises
                report.skipped.append(f"{point_id}: {log_path} unreadable ({type(exc).__name__}: {exc})")
                continue
            if not n:
                report.current += 1
                continue
            size = path.stat().st_size
            report.rewritten += 1
            report.bytes_before += size
            report.bytes_after += size + _INDEX_BYTES * n
    return report


def upgrade_logs(directory: Path, *, progress: Callable[[str], None] | None = None) -> UpgradeReport:
    """Rewrite every finished point's old-layout log (see the module); ``progress`` is told a line
    after each batch. CampaignError while another process holds the directory's lock."""
    from labrunner.logs import read_run
    from labrunner.logs.upgrade import rewrite, same_run, unindexed_messages

    start = time.monotonic()
    report = UpgradeReport()
    ledger_path(directory)  # a directory that is no campaign's is refused before its lock is made
    with DirectoryLock(directory, "upgrade-logs"), Ledger.open(directory) as ledger:
        seal.clear(ledger)
        report.finished = _finish(ledger, json.loads(ledger.meta().get(JOURNAL_KEY) or "{}"), report)
        logs = _logs(ledger)
        for stale in {(directory / p).parent for _, p in logs}:
            for leftover in stale.glob(f"{TMP_PREFIX}*{_SUFFIX}"):  # written, never journaled
                leftover.unlink()
        done = 0
        for batch in _batches(logs, BATCH):
            pending: dict[str, list[str]] = {}
            for point_id, log_path in batch:
                path = directory / log_path
                tmp = path.with_name(f"{TMP_PREFIX}{point_id}{_SUFFIX}")
                if not path.exists():
                    report.skipped.append(f"{point_id}: {log_path}: missing (`labrunner resume` reruns its point)")
                    continue
                try:
                    if not unindexed_messages(path):
                        report.current += 1
                        continue
                    old = read_run(path)
                    _check(old, point_id)
                    with open(tmp, "wb") as fh:
                        rewrite(path, fh)
                        os.fchmod(fh.fileno(), stat.S_IMODE(path.stat().st_mode))  # as the log was
                        os.fsync(fh.fileno())
                    same_run(old, tmp)
                except OSError:  # the environment's (a full disk, permissions): stop, the CLI says where
                    tmp.unlink(missing_ok=True)
                    raise
                except Exception as exc:  # a log that cannot be read, rewritten or proved: left as it is
                    report.skipped.append(f"{point_id}: {log_path}: {type(exc).__name__}: {exc}")
                    tmp.unlink(missing_ok=True)
                    continue
                report.bytes_before += path.stat().st_size
                report.bytes_after += tmp.stat().st_size
                pending[point_id] = [log_path, tmp.name]
            if pending:
                for parent in {(directory / p).parent for p, _ in pending.values()}:
                    fsync_dir(parent)  # the temporary files exist before the journal names them
                ledger.set_meta(JOURNAL_KEY, json.dumps(pending, sort_keys=True))
                _finish(ledger, pending, report)
                report.rewritten += len(pending)
            done += len(batch)
            if progress is not None:
                progress(f"upgrade-logs: {done}/{len(logs)} logs checked, {report.rewritten} rewritten")
        seal.seal(ledger)
    report.seconds = time.monotonic() - start
    return report


def _check(log: RunLog, point_id: str) -> None:
    """UpgradeError unless ``log`` is a complete, undamaged run of ``point_id``."""
    from labrunner.logs.upgrade import UpgradeError
    from labrunner.run_identity import mismatch

    why = "torn" if log.torn else log.damaged or ("no outcome record" if log.outcome is None else "")
    why = why or mismatch(log.metadata, point_id)
    if why:
        raise UpgradeError(f"left as it is ({why})")


def _finish(ledger: Ledger, pending: dict[str, list[str]], report: UpgradeReport) -> int:
    """Steps 2 and 3 for a journaled batch (see the module); return how many logs it held."""
    if not pending:
        return 0
    directory = ledger.directory
    renamed = set()
    for point_id, (log_path, tmp_name) in pending.items():
        final = directory / log_path
        tmp = final.with_name(tmp_name)
        if tmp.exists():
            os.replace(tmp, final)
            renamed.add(point_id)
    for parent in {(directory / p).parent for p, _ in pending.values()}:
        fsync_dir(parent)
    fingerprints = {}
    for point_id, (log_path, _) in pending.items():
        final = directory / log_path
        if point_id in renamed:
            fingerprints[point_id] = fingerprint(final)
            continue
        found, why = verify_log(final, point_id)  # renamed by the interrupted run (or moved away since)
        if found is None:
            report.skipped.append(f"{point_id}: {log_path}: {why}")
        else:
            fingerprints[point_id] = found["fingerprint"]
    ledger.set_fingerprints(fingerprints, {JOURNAL_KEY: None})
    return len(pending)
