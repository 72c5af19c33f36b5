"""Settling a campaign directory after a crash, before ``resume`` runs anything.

What a killed runner can leave behind, and what happens to it:

- ``runs/.tmp-<id>-…mcap`` — a log still being written (torn or complete but unpublished):
  moved to ``quarantine/`` and recorded; its point reruns.
- a *claimed* (or planned) row whose ``runs/<id>.mcap`` exists — the worker published the log but
  the parent died before committing the row. The log was fsynced and renamed only after its
  outcome record was written, so it is a complete run: it is **accepted** if it opens without
  salvage, carries an outcome and names this point; the row is committed from the log's outcome
  and metrics (``outcome_json.recovered = true``). A file that fails any of these checks is
  quarantined and the point reruns. Accepting (rather than always rerunning) keeps a finished
  run on a real rig — an experiment that cost wear and time — instead of repeating it.
- a *claimed* row without a log — the run was cut short: back to ``planned``.
- a terminal row whose log has disappeared — back to ``planned`` (nothing may be missing).

:func:`recover` finds them by one listing of ``runs/`` and one pass over the rows. After a crash
that the session journal vouches for (:mod:`.journal`: only the claimed points can be unsettled),
:func:`settle_running` settles the claimed points alone, a ``stat`` each, and leaves their
temporary logs to the end of the session (:func:`sweep`, before the directory is sealed).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from pathlib import Path

from labrunner import safefs
from labrunner.campaign import seal
from labrunner.campaign.ledger import TERMINAL, Ledger, RunRecord, fsync_dir
from labrunner.campaign.worker import RUNS_DIR, TMP_PREFIX, final_path, ledger_outcome
from labrunner.engine import Outcome

QUARANTINE_DIR = "quarantine"


@dataclass
class Recovery:
    """What :func:`recover` did."""

    accepted: list[str] = field(default_factory=list)
    quarantined: list[str] = field(default_factory=list)
    replanned: list[str] = field(default_factory=list)
    lost: list[str] = field(default_factory=list)
    #: ``runs/``'s stat before its listing when nothing was moved out of it: the directory is then
    #: consistent as listed, and :func:`labrunner.campaign.seal.adopt` can seal it without a second listing.
    listed: dict[str, int] | None = None
    #: Only the claimed points were settled (:func:`settle_running`): the rest is checked when the session ends.
    running_only: bool = False

    def describe(self) -> str:
        parts = [
            f"{len(self.accepted)} published run(s) accepted",
            f"{len(self.quarantined)} file(s) quarantined",
            f"{len(self.replanned)} interrupted point(s) to rerun",
        ]
        if self.lost:
            parts.append(f"{len(self.lost)} missing log(s) to rerun")
        if self.running_only:
            parts.append("the running points only (session journal; every check runs when this session ends)")
        return ", ".join(parts)


def quarantine(ledger: Ledger, path: Path, point_id: str | None, reason: str) -> str:
    """Move ``path`` into ``DIR/quarantine/`` (unique name), record it; return the new relative path."""
    directory = ledger.directory
    qdir = directory / QUARANTINE_DIR
    safefs.mkdir(qdir)
    target = qdir / f"{path.name.lstrip('.')}.{time.time_ns()}"
    size = path.stat().st_size
    safefs.replace(path, target)
    fsync_dir(qdir)
    fsync_dir(path.parent)
    moved = str(target.relative_to(directory))
    ledger.record_quarantine(point_id, str(path.relative_to(directory)), moved, reason, size)
    return moved


def _tmp_point(name: str) -> str | None:
    """Point id from ``.tmp-<id>-<pid>-<token>.mcap``."""
    stem = name.removeprefix(TMP_PREFIX)
    return stem.split("-", 1)[0] or None


def verify_log(path: Path, point_id: str) -> tuple[dict | None, str]:
    """(log summary, "") if ``path`` is a complete log of ``point_id``, else (None, reason); the
    summary holds the log's :func:`~labrunner.run_identity.fingerprint`, taken before it was read
    (what the ledger records for the log)."""
    from labrunner.logs import read_run
    from labrunner.run_identity import fingerprint, mismatch, named_point

    try:
        stat = fingerprint(path)  # before the read: a change after it gives another fingerprint
        log = read_run(path)
    except Exception as exc:  # any unreadable file is quarantined, whatever the library raises
        return None, f"unreadable: {type(exc).__name__}: {exc}"
    run = log.metadata.get("run", {})
    if log.torn:
        return None, "torn (no footer)"
    if log.damaged:
        return None, f"damaged: {log.damaged}"
    if log.outcome is None:
        return None, "no outcome record"
    if mismatch(log.metadata, point_id):
        return None, f"names point {named_point(log.metadata)!r}"
    found = {"outcome": dict(log.outcome), "metrics": dict(log.metadata.get("metrics", {})), "run": run}
    return {**found, "diagnostics": log.metadata.get("diagnostics"), "fingerprint": stat}, ""


def outcome_record(found: dict) -> dict:
    """A log's outcome (``found``: :func:`verify_log`'s summary) as the worker commits it: the log
    keeps only the fields that are set (and its sample count), the ledger every field of
    :class:`~labrunner.engine.Outcome`, plus a real rig's ``diagnostics`` record under
    ``diagnostics`` (:func:`labrunner.campaign.worker.ledger_outcome`; logs written before the
    outcome record had one shape nest it in the outcome). Recovery and ``repair`` both commit runs
    from their logs."""
    logged = found["outcome"]
    keys = [f.name for f in fields(Outcome)]
    outcome = Outcome(**{k: logged[k] for k in keys if k in logged}).as_dict()
    return ledger_outcome(outcome, found.get("diagnostics") or logged.get("diagnostics"))


def recover(ledger: Ledger) -> Recovery:
    """Bring the directory and the ledger into agreement (see the module docstring)."""
    directory = ledger.directory
    runs = directory / RUNS_DIR
    safefs.mkdir(runs)
    report = Recovery()
    # one listing of runs/ instead of a stat a point: ~1 s rather than ~10 s at 10^6 points
    listed, names = seal.listing(ledger)
    report.quarantined += _quarantine_temporary(ledger, names)

    def exists(relative: str) -> bool:
        folder, _, name = relative.rpartition("/")
        return name in names if folder == RUNS_DIR else (directory / relative).exists()

    # one pass over the table in grid order, read before anything is written (the state index
    # would look each of 10^6 rows up again: seconds): unfinished points whose log is published,
    # claimed points, finished points whose log is gone
    published: list[tuple[str, str]] = []
    for pid, state, log_path in seal.log_rows(ledger):
        if state in TERMINAL:
            if log_path and not exists(log_path):
                report.lost.append(pid)
        elif f"{pid}.mcap" in names:
            published.append((pid, state))
        elif state == "claimed":
            report.replanned.append(pid)
    _settle_published(ledger, published, report)
    ledger.replan(report.replanned + report.lost)
    report.listed = None if report.quarantined else listed
    return report


def _settle_published(ledger: Ledger, published: list[tuple[str, str]], report: Recovery) -> None:
    """Accept each unfinished point's published log (``published``: id, state) that proves a
    complete run of it, committing its row from the log; quarantine any other (its point reruns)."""
    directory = ledger.directory
    for pid, state in published:
        path = directory / final_path(pid)
        found, reason = verify_log(path, pid)
        if found is None:
            report.quarantined.append(quarantine(ledger, path, pid, f"published log rejected: {reason}"))
            if state == "claimed":
                report.replanned.append(pid)
            continue
        outcome = {**outcome_record(found), "recovered": True}
        ledger.commit(
            RunRecord(
                point_id=pid,
                outcome=outcome["status"],
                outcome_record=outcome,
                metrics=found["metrics"],
                log_path=final_path(pid),
                host=str(found["run"].get("host", "")),
                pid=int(found["run"].get("pid", 0)),
                finished_at=path.stat().st_mtime,
                log_fingerprint=found["fingerprint"],
            ),
            from_states=(state,),
        )
        report.accepted.append(pid)


def settle_running(ledger: Ledger) -> Recovery:
    """Settle the claimed points only (:mod:`.journal` vouches that nothing else is unsettled): a
    published log is accepted or quarantined as by :func:`recover`, no log → back to ``planned``;
    their temporary logs wait for :func:`sweep`."""
    report = Recovery(running_only=True)
    published = []
    for (pid,) in ledger.db.execute("SELECT id FROM points WHERE state = 'claimed' ORDER BY seq").fetchall():
        if (ledger.directory / final_path(pid)).exists():
            published.append((pid, "claimed"))
        else:
            report.replanned.append(pid)
    _settle_published(ledger, published, report)
    ledger.replan(report.replanned)
    return report


def sweep(ledger: Ledger) -> int:
    """Quarantine the temporary logs left in ``runs/`` (call only while no batch of this campaign
    runs: at the end of a session); return how many."""
    return len(_quarantine_temporary(ledger, seal.listing(ledger)[1]))


def _quarantine_temporary(ledger: Ledger, names: set[str]) -> list[str]:
    """Quarantine the temporary logs among ``runs/``'s ``names``; their new relative paths."""
    runs = ledger.directory / RUNS_DIR
    temporary = sorted(n for n in names if n.startswith(TMP_PREFIX))
    return [quarantine(ledger, runs / n, _tmp_point(n), "unpublished temporary log") for n in temporary]
