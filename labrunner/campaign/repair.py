"""``labrunner repair DIR``: rebuild a damaged or deleted ledger from the campaign copy and the logs.

What a ledger holds is derivable, except for runs that left no log: the grid comes from the
campaign file (``DIR/campaign.toml``, or the copy the old ledger keeps), every published log
``runs/<id>.mcap`` that is complete and names its point gives that point's terminal row (outcome,
metrics, attempt, host), as :mod:`labrunner.campaign.recovery` accepts logs after a crash. So
nothing that was published is lost. What the old ledger still says is kept where it can be read:
its creation metadata, sessions, quarantine records, and ``failed`` rows (a failed run has no log).
Every other point is ``planned`` and runs on ``resume``. The old file (with its -wal/-shm) is moved
into ``DIR/quarantine/``, never deleted; the new ledger is written atomically and then checked.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labrunner import safefs
from labrunner.campaign import integrity, plan_inputs, spec
from labrunner.campaign.ledger import LEDGER_NAME, Ledger, RunRecord, fsync_dir
from labrunner.campaign.lock import DirectoryLock
from labrunner.campaign.recovery import QUARANTINE_DIR, outcome_record, verify_log
from labrunner.campaign.status import REAL_RIG
from labrunner.campaign.worker import final_path
from labrunner.errors import InvalidParameter
from labrunner.run_identity import FINGERPRINT_COLUMNS, fingerprint

COPY = "campaign.toml"


@dataclass
class Repaired:
    """What :func:`repair` did."""

    points: int = 0
    from_logs: int = 0
    failed_kept: int = 0
    rejected: list[str] = field(default_factory=list)  # logs that could not be used (why)
    old: str = ""  # where the old ledger went ("" if there was none)
    problem: str = ""  # what was wrong with it

    def describe(self) -> str:
        parts = [f"{self.points} points", f"{self.from_logs} published run(s) restored from their logs"]
        if self.failed_kept:
            parts.append(f"{self.failed_kept} failed point(s) kept from the old ledger")
        if self.rejected:
            parts.append(f"{len(self.rejected)} log(s) unusable (they rerun)")
        left = self.points - self.from_logs - self.failed_kept
        parts.append(f"{left} to run")
        old = f"; old ledger ({self.problem or 'sound'}) moved to {self.old}" if self.old else ""
        return ", ".join(parts) + old


def _old_ledger(path: Path) -> tuple[dict[str, str], list[dict[str, Any]], list[dict], list[dict], str]:
    """(meta, failed rows, sessions, quarantine rows, problem) of whatever the old ledger still holds."""
    if not path.is_file():
        return {}, [], [], [], "missing"
    meta: dict[str, str] = {}
    failed: list[dict[str, Any]] = []
    sessions: list[dict] = []
    quarantine: list[dict] = []
    try:
        db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error as exc:
        return {}, [], [], [], f"unreadable: {exc}"
    db.row_factory = sqlite3.Row
    with contextlib.closing(db):
        problem = integrity.problem(db)
        for query, sink in (
            ("SELECT key, value FROM meta", None),
            ("SELECT * FROM points WHERE state = 'failed'", failed),
            ("SELECT * FROM sessions ORDER BY n", sessions),
            ("SELECT * FROM quarantine ORDER BY n", quarantine),
        ):
            with contextlib.suppress(sqlite3.Error):  # a damaged file: keep what can be read
                rows = db.execute(query).fetchall()
                if sink is None:
                    meta = {r[0]: r[1] for r in rows}
                else:
                    sink.extend(dict(r) for r in rows)
    return meta, failed, sessions, quarantine, problem


def _campaign(directory: Path, meta: dict[str, str], source: str | Path | None) -> spec.Campaign:
    """The stored campaign: ``DIR/campaign.toml`` (else the old ledger's copy), its rig resolved
    from ``source`` (the original file's path), else from the path the old ledger recorded."""
    copy = directory / COPY
    if copy.is_file():
        text = copy.read_text(encoding="utf-8")
    elif meta.get("campaign_file"):
        text = meta["campaign_file"]
    else:
        raise InvalidParameter(
            "DIR",
            f"{str(directory)!r} has neither {COPY} nor a readable ledger keeping the "
            "campaign: nothing to rebuild the grid from",
        )
    path = Path(source) if source else Path(meta["campaign_path"]) if meta.get("campaign_path") else copy
    return spec.from_text(text, source_path=path)


def _sound(path: Path) -> bool:
    """Whether the ledger passes every integrity check and every log it names is there, whole
    and its own point's (then a repair would only replace a good ledger by a copy of it): a log
    is proved by the fingerprint the ledger recorded (unchanged since), else read
    (:func:`~labrunner.campaign.recovery.verify_log`: a truncated, zeroed, damaged or swapped
    log fails it, and a repair is then what the directory needs)."""
    if not path.is_file():
        return False
    try:
        db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error:
        return False
    with contextlib.closing(db):
        if integrity.problem(db):
            return False
        try:
            columns = {r[1] for r in db.execute("PRAGMA table_info(points)")}
            recorded = ", ".join(c if c in columns else "NULL" for c in FINGERPRINT_COLUMNS)
            logs = db.execute(f"SELECT id, log_path, {recorded} FROM points WHERE log_path IS NOT NULL").fetchall()
        except sqlite3.Error:
            return False
    for point_id, log, *stamp in logs:
        where = path.parent / log
        try:
            if tuple(stamp) == fingerprint(where):
                continue
        except OSError:
            return False
        if verify_log(where, point_id)[0] is None:
            return False
    return True


def _quarantine(path: Path, directory: Path) -> str:
    """Move the old ledger and its -wal/-shm into quarantine/; return the ledger's new relative path."""
    qdir = directory / QUARANTINE_DIR
    safefs.mkdir(qdir)
    stamp = time.time_ns()
    moved = ""
    for suffix in ("", "-wal", "-shm"):
        old = Path(f"{path}{suffix}")
        if old.exists():
            target = qdir / f"{LEDGER_NAME}{suffix}.{stamp}"
            safefs.replace(old, target)
            moved = moved or str(target.relative_to(directory))
    fsync_dir(qdir)
    fsync_dir(directory)
    return moved


def repair(directory: str | Path, *, campaign_file: str | Path | None = None, force: bool = False) -> Repaired:
    """Rebuild ``DIR/ledger.sqlite`` (see the module docstring); takes the directory's lock. A
    ledger that passes every integrity check is left alone unless ``force``."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InvalidParameter(
            "DIR",
            f"{str(directory)!r} does not exist"
            if not directory.exists()
            else f"{str(directory)!r} is not a directory",
        )
    path = directory / LEDGER_NAME
    if not (directory / COPY).is_file() and not path.is_file():
        raise InvalidParameter(
            "DIR",
            f"{str(directory)!r} has neither {COPY} nor a ledger keeping the campaign: "
            "nothing to rebuild the grid from",
        )
    if not force and _sound(path):  # before the lock: a refused repair touches nothing
        raise InvalidParameter(
            "DIR",
            f"the ledger of {str(directory)!r} is sound (every integrity check passes, every run's log is there, "
            "whole and its own point's): "
            "nothing to repair; "
            f"`labrunner resume {directory}` continues it, `labrunner repair --force {directory}` rebuilds it anyway",
        )
    with DirectoryLock(directory, "repair"):
        meta, failed, sessions, quarantine, problem = _old_ledger(path)
        campaign = _campaign(directory, meta, campaign_file)
        if campaign.guided is not None:
            raise InvalidParameter(
                "DIR", "a guided campaign's rounds cannot be rebuilt from its file; its logs stay in runs/"
            )
        points, checksum = spec.plan(campaign)
        report = Repaired(points=len(points), problem=problem)
        restored: list[tuple[RunRecord, int]] = []
        for p in points:
            log = directory / final_path(p.id)
            if not log.exists():
                continue
            found, reason = verify_log(log, p.id)
            if found is None:
                report.rejected.append(f"{final_path(p.id)}: {reason}")
                continue
            outcome = outcome_record(found)
            run = found["run"]
            restored.append(
                (
                    RunRecord(
                        point_id=p.id,
                        outcome=outcome["status"],
                        outcome_record=outcome,
                        metrics=found["metrics"],
                        log_path=final_path(p.id),
                        host=str(run.get("host", "")),
                        pid=int(run.get("pid", 0)),
                        finished_at=log.stat().st_mtime,
                        log_fingerprint=found["fingerprint"],
                    ),
                    int(run.get("attempt", 1)),
                )
            )
        new_meta = {
            "campaign": campaign.name,
            "campaign_file": campaign.source,
            "plan_checksum": checksum,
            **plan_inputs.stamp(campaign),
            "points": str(len(points)),
            "rig": campaign.rig,
            REAL_RIG: "1" if not campaign.rig_info.simulated else "0",
            "campaign_path": meta.get("campaign_path") or str(Path(campaign_file or directory / COPY).resolve()),
            "created_at": meta.get("created_at", repr(time.time())),
            "created_by": meta.get("created_by", "repair"),
            "repaired_at": repr(time.time()),
        }
        if path.exists():
            report.old = _quarantine(path, directory)
        else:  # a deleted ledger's stray -wal/-shm must not be read as the new one's
            for suffix in ("-wal", "-shm"):
                Path(f"{path}{suffix}").unlink(missing_ok=True)
        by_id = {p.id: p for p in points}
        with Ledger.create(
            directory, meta=new_meta, points=((p.seq, p.id, p.parameters, p.batch_key) for p in points)
        ) as ledger:
            del points
            for record, attempt in restored:
                ledger.commit(record, from_states=("planned",))
                ledger.db.execute("UPDATE points SET attempts = ? WHERE id = ?", (attempt, record.point_id))
            report.from_logs = len(restored)
            published = {r.point_id for r, _ in restored}
            for row in failed:
                if row["id"] in by_id and row["id"] not in published:
                    ledger.commit(_failed_record(row), from_states=("planned",))
                    ledger.db.execute("UPDATE points SET attempts = ? WHERE id = ?", (row["attempts"], row["id"]))
                    report.failed_kept += 1
            _copy_history(ledger, sessions, quarantine)
            if report.old:
                ledger.record_quarantine(
                    None,
                    LEDGER_NAME,
                    report.old,
                    f"ledger replaced by repair ({problem or 'sound'})",
                    (directory / report.old).stat().st_size,
                )
            integrity.verify(ledger.db, path)
    return report


def _failed_record(row: dict[str, Any]) -> RunRecord:
    try:
        outcome = json.loads(row.get("outcome_json") or "{}")
    except ValueError:
        outcome = {}
    outcome = {"status": "failed", **(outcome if isinstance(outcome, dict) else {})}
    return RunRecord(
        point_id=row["id"],
        outcome="failed",
        outcome_record=outcome,
        metrics={},
        log_path=None,
        host=str(row.get("host") or ""),
        pid=int(row.get("pid") or 0),
        finished_at=float(row.get("finished_at") or time.time()),
    )


def _copy_history(ledger: Ledger, sessions: list[dict], quarantine: list[dict]) -> None:
    """The old sessions (for elapsed time and rate) and quarantine records, as far as readable."""
    with contextlib.suppress(sqlite3.Error, KeyError, TypeError):
        ledger.db.execute("BEGIN IMMEDIATE")
        ledger.db.executemany(
            "INSERT INTO sessions (command, host, pid, started_at, last_at, ended_at, end_reason) VALUES (?, ?, ?, ?, ?, ?, ?)",
            [
                (s["command"], s["host"], s["pid"], s["started_at"], s["last_at"], s["ended_at"], s["end_reason"])
                for s in sessions
            ],
        )
        ledger.db.executemany(
            "INSERT INTO quarantine (point_id, original, moved_to, reason, bytes, at) VALUES (?, ?, ?, ?, ?, ?)",
            [(q["point_id"], q["original"], q["moved_to"], q["reason"], q["bytes"], q["at"]) for q in quarantine],
        )
        ledger.db.execute("COMMIT")
    if ledger.db.in_transaction:
        ledger.db.execute("ROLLBACK")
