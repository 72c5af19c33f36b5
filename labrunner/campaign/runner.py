"""The three campaign operations behind ``labrunner run``, ``resume`` and ``status``.

``start`` validates the whole campaign (every point) before it creates anything, refuses a
directory that already holds a campaign, creates the directory, takes its lock, writes the
ledger atomically and runs. ``resume`` takes the lock (a dead runner's lock is taken over),
runs the campaign's own stored copy (an edited original is only noted), refuses a campaign
whose rig file or planning code changed what would run, settles what a crash left behind
(:mod:`labrunner.campaign.recovery`) and runs what is left. ``status`` only reads.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sqlite3
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from labrunner import safefs
from labrunner.campaign import dry_run, guided_run, integrity, journal, live_view, plan_inputs, recovery, seal, spec
from labrunner.campaign.executors import ExecutorHandle, check_executor_url, open_executor
from labrunner.campaign.ledger import LEDGER_NAME, Ledger, LedgerWriteError, fsync_dir
from labrunner.campaign.lock import LOCK_NAME, DirectoryLock
from labrunner.campaign.progress import Progress
from labrunner.campaign.scheduler import Outcome, Scheduler, StopSignals
from labrunner.campaign.status import REAL_RIG, status  # noqa: F401 - ``status`` is one of the three operations
from labrunner.campaign.worker import RUNS_DIR
from labrunner.errors import CampaignError, InvalidParameter, LabrunnerError
from labrunner.version import __version__

CAMPAIGN_COPY = "campaign.toml"
RIG_LINK = "rig_link"  # ledger meta: the --port / --interface / --channel a real rig's campaign was run with


@dataclass(frozen=True)
class Options:
    """How to execute: process-pool size or Dask address, batch size, where progress goes, and
    where the live view listens (``--live``; None: nothing listens)."""

    workers: int | None = None
    executor: str | None = None
    batch_size: int | None = None
    stream: TextIO | None = None
    progress_interval_s: float = 5.0
    live: live_view.Address | None = None
    link: Mapping[str, str | None] | None = None  # a real rig's --port, --interface, --channel (stored for resume)


def default_directory(campaign: spec.Campaign) -> Path:
    return Path("data") / campaign.name


def _ours(path: Path) -> bool:
    """Files a run may leave before its ledger exists (its lock, a half-written ledger)."""
    return path.name == LOCK_NAME or path.name.startswith(f".{LEDGER_NAME}.")


def _check_new_directory(directory: Path, name: str, checksum: str) -> None:
    """Refuse a directory that holds a campaign (naming it: this one, an edited version, another)
    or other files."""
    if (directory / LEDGER_NAME).exists():
        try:
            with Ledger.open_readonly(directory, verify=False) as ledger:
                meta = ledger.meta()
        except (LabrunnerError, sqlite3.Error):
            meta = {}
        other = meta.get("campaign", "?")
        if other == name and meta.get("plan_checksum") != checksum:
            raise CampaignError(
                f"{directory} already holds campaign {name!r} planned from another version of this file (grid or "
                f"settings differ); run this file with --out DIR, or continue the stored one with "
                f"`labrunner resume {directory}`"
            )
        what = "this campaign" if other == name else f"campaign {other!r}"
        raise CampaignError(
            f"{directory} already holds {what}; continue it with `labrunner resume {directory}`, or start over "
            f"in another directory with --out DIR (or delete {directory} first)"
        )
    if directory.exists() and (not directory.is_dir() or any(not _ours(p) for p in directory.iterdir())):
        raise CampaignError(f"{directory} exists and is not an empty campaign directory; choose another --out")


def _write_copy(directory: Path, text: str) -> None:
    safefs.write_atomic(directory / CAMPAIGN_COPY, text.encode("utf-8"))


def start(file: str | Path, out: str | Path | None, opts: Options, *, dry: bool = False) -> tuple[Outcome | None, str]:
    """``labrunner run``: validate everything, then create the campaign directory and run it."""
    check_executor_url(opts.executor, reach=False)
    campaign = spec.load(file, link=opts.link)
    if out is not None and not str(out).strip():
        raise InvalidParameter("--out", f"must be a path, got {str(out)!r}")
    directory = Path(out) if out is not None else default_directory(campaign)
    for path in (Path(file), directory):  # before anything is created: the ledger records them as UTF-8
        str(path.resolve()).encode("utf-8")
    if dry:
        return None, _dry_run(campaign, directory, opts)
    # the view's server threads start after the pool's workers are forked, and it listens before anything is created
    with _early_pool(campaign, opts) as pool, live_view.serve(opts.live, campaign.name, opts.stream) as view:
        points, checksum = spec.plan(campaign)
        _check_new_directory(directory, campaign.name, checksum)
        warned = link_warning(campaign, points)
        if warned:
            print(warned, file=opts.stream or sys.stderr)
        check_executor_url(opts.executor)  # reached before the directory exists
        directory.mkdir(parents=True, exist_ok=True)
        with DirectoryLock(directory, "run") as lock:
            _check_new_directory(directory, campaign.name, checksum)  # again, now that nobody else can create it
            meta = {
                "campaign": campaign.name,
                "campaign_file": campaign.source,
                "campaign_path": str(Path(file).resolve()),
                "plan_checksum": checksum,
                **plan_inputs.stamp(campaign),
                "points": str(len(points)),
                "rig": campaign.rig,
                REAL_RIG: "1" if not campaign.rig_info.simulated else "0",
                "created_at": repr(time.time()),
                "created_by": f"labrunner {__version__} on {socket.gethostname()}",
                **({"guided": campaign.guided.name} if campaign.guided is not None else {}),
                **({"metadata": json.dumps(campaign.metadata)} if campaign.metadata else {}),
                **({RIG_LINK: json.dumps(campaign.rig_link)} if campaign.rig_link else {}),
            }
            points_rows = ((p.seq, p.id, p.parameters, p.batch_key) for p in points)
            ledger = Ledger.create(directory, meta=meta, points=points_rows)
            del points, points_rows
            _write_copy(directory, campaign.source)  # the ledger exists first: it is what marks the campaign
            safefs.mkdir(directory / RUNS_DIR)
            with ledger:
                return _execute(campaign, ledger, lock, opts, "run", pool, view=view), str(directory)


def _dry_run(campaign: spec.Campaign, directory: Path, opts: Options) -> str:
    """``labrunner run --dry-run``: what would run, and whether ``run`` would refuse the directory."""
    points, checksum = spec.plan(campaign)
    slots = opts.workers or len(os.sched_getaffinity(0)) if campaign.rig_info.simulated else 1
    if campaign.guided is not None:
        text = dry_run.guided_text(campaign, points, slots)
    else:
        text = dry_run.grid_text(campaign, points, slots, opts.batch_size)
    try:
        _check_new_directory(directory, campaign.name, checksum)
    except CampaignError as exc:
        text += f"\nnote: `labrunner run` would refuse: {exc}"
    warned = link_warning(campaign, points)
    return f"{text}\n{warned}" if warned else text


def link_warning(campaign: spec.Campaign, points: list[spec.PlannedPoint]) -> str:
    """A real rig's host loop asked for a higher f_s than ``check-rig`` last measured its link to
    sustain (:mod:`labrunner.rigs.transports.link_record`): one line, else ""."""
    config = campaign.rig_config
    if campaign.rig_info.simulated or config.parameters.get("loop", "host") != "host":
        return ""
    from labrunner.rigs.config import resolve_rig_file
    from labrunner.rigs.transports import link_record

    rig_file = campaign.rig_path or resolve_rig_file(campaign.rig, campaign.rig_search)
    fs = max((float(p.parameters.get("campaign.fs", campaign.fs)) for p in points), default=campaign.fs)
    return link_record.warning(link_record.link_key(rig_file, config.kind, config.parameters), fs)


def _early_pool(
    campaign: spec.Campaign, opts: Options, lock_fd: int | None = None
) -> contextlib.AbstractContextManager[ExecutorHandle | None]:
    """The local process pool of a simulated campaign, forked before the slow part of starting
    (validating every point, settling a crash) so that its workers load the engine meanwhile, on
    the other cores; None for a real rig or Dask, whose executor :func:`_execute` opens itself
    once the campaign is known to be good."""
    if opts.executor or not campaign.rig_info.simulated:
        return contextlib.nullcontext()
    return open_executor(real_rig=False, workers=opts.workers, url=None, lock_fd=lock_fd, signals=opts.live is not None)


def _check_unchanged(ledger: Ledger, link: Mapping[str, str | None] | None = None) -> spec.Campaign:
    """The stored campaign; refuse if it plans differently now (its rig file or labrunner changed).

    When the plan's inputs (file, rig file, planning code: :mod:`.plan_inputs`) are those stored,
    the plan is the stored one and the ledger's ids were checked against their creation checksum
    (a ledger that keeps none is re-planned); otherwise the campaign is re-planned (0.2–1 ms a
    point) and compared, and the inputs that planned the same are stored for the next resume."""
    meta = ledger.meta()
    lacking = [k for k in ("campaign_file", "campaign_path", "plan_checksum") if k not in meta]
    if lacking:
        raise integrity.damaged(ledger.directory / LEDGER_NAME, f"keeps no {', '.join(lacking)} to resume from")
    source_path = Path(meta["campaign_path"])
    given = {k: v for k, v in (link or {}).items() if v is not None}
    if given and given != json.loads(meta.get(RIG_LINK, "{}")):
        ledger.set_meta(RIG_LINK, json.dumps(given))  # the device moved (another pty): kept for the next resume
    campaign = spec.from_text(
        meta["campaign_file"], source_path=source_path, link=given or json.loads(meta.get(RIG_LINK, "{}"))
    )
    if "ids_checksum" not in meta or not plan_inputs.unchanged(campaign, meta):
        _check_replanned(ledger, campaign, meta["plan_checksum"])
        if "ids_checksum" in meta:
            for key, value in plan_inputs.stamp(campaign).items():
                ledger.set_meta(key, value)
    return campaign


def _edited_note(ledger: Ledger) -> str:
    """One line when the campaign's original file differs from the copy the campaign keeps: resume
    runs the copy (editing a file to make a variant is the normal workflow), and says so."""
    meta = ledger.meta()
    source_path = Path(meta["campaign_path"])
    try:
        edited = source_path.read_text(encoding="utf-8") != meta["campaign_file"]
    except (OSError, UnicodeDecodeError):  # moved, deleted or unreadable: the copy is all there is
        edited = False
    if not edited:
        return ""
    return (
        f"note: {source_path} changed since this campaign began; resuming from its own copy, "
        f"{ledger.directory / CAMPAIGN_COPY} (run the edited file as a new campaign with --out DIR)"
    )


def _check_replanned(ledger: Ledger, campaign: spec.Campaign, checksum: str) -> None:
    """Plan the stored campaign again: its points must be the ledger's and its checksum the stored one."""
    points, replanned = spec.plan(campaign)
    if campaign.guided is None:  # a guided campaign's rows are its rounds, not the plan's points
        integrity.check_plan(ledger.directory / LEDGER_NAME, ledger.ids(), [p.id for p in points])
    del points
    if replanned != checksum:
        raise CampaignError(
            f"the campaign stored in {ledger.directory} no longer plans the same runs (rig file or labrunner "
            "changed?); resuming would mix two campaigns — start a new one with `labrunner run FILE --out DIR`"
        )


def resume(directory: str | Path, opts: Options, *, retry_failed: bool = False) -> tuple[Outcome, str]:
    """``labrunner resume``: settle a crash, then run every point that is not terminal.

    A directory sealed when its last session ended (:mod:`.seal`: every check passed, nothing to
    settle, ``runs/`` untouched since) is trusted as it is; after a crash that the session journal
    vouches for (:mod:`.journal`) only the points that were running are settled, the rest checked
    when this session ends; any other is checked row by row and settled (:mod:`.recovery`)."""
    directory = Path(directory)
    check_executor_url(opts.executor, reach=False)
    # a missing, foreign or damaged ledger: exit 2 before the lock file is made (the checks that
    # read every row only when the seal will not vouch for them; under the lock they are not repeated)
    with Ledger.open_readonly(directory, thorough=False) as ledger:
        checked = not (seal.runs_unchanged(ledger) or journal.kept(ledger))
        if checked:
            integrity.verify(ledger.db, ledger.directory / LEDGER_NAME)
    runs = directory / RUNS_DIR
    if runs.exists() and not runs.is_dir():
        raise CampaignError(
            f"{runs} is a file, not the directory of the campaign's run logs: move it away, then resume"
        )
    check_executor_url(opts.executor)
    stream = opts.stream or sys.stderr
    with DirectoryLock(directory, "resume") as lock, Ledger.open(directory, verify=False) as ledger:
        trust, (counts, words) = _trusted(ledger, checked)
        if lock.took_over:
            print(f"took over the stale lock of {lock.took_over.describe()}", file=stream)
        campaign = _check_unchanged(ledger, opts.link)
        note = _edited_note(ledger)
        if note:
            print(note, file=stream)
        idle = not (counts.get("planned", 0) or counts.get("claimed", 0) or (retry_failed and counts.get("failed", 0)))
        # a finished campaign needs no workers: forking a pool only to wait for its shutdown cost ~1 s
        early = contextlib.nullcontext() if idle and campaign.guided is None else _early_pool(campaign, opts, lock.fd)
        with early as pool, live_view.serve(opts.live, campaign.name, stream) as view:  # the workers load meanwhile
            _write_copy(ledger.directory, ledger.meta()["campaign_file"])
            if trust == "sealed":
                report = recovery.Recovery()  # nothing to settle: the seal says so
            elif trust == "journal":
                report = recovery.settle_running(ledger)  # only the running points can be unsettled
            else:
                seal.clear(ledger)
                report = recovery.recover(ledger)
                seal.adopt(ledger, report.listed)  # settled: sealed from recovery's listing, not a second one
            print(f"resume {directory}: {report.describe()}", file=stream)
            if retry_failed:
                failed = [r["id"] for r in ledger.rows(("failed",), "id")]
                if failed:
                    seal.clear(ledger)
                    ledger.replan(failed)
                print(f"retrying {len(failed)} failed point(s)", file=stream)
            unchanged = trust == "sealed" and not retry_failed  # else: settling may have changed the states
            census = (counts, words) if unchanged else None
            return _execute(campaign, ledger, lock, opts, "resume", pool, census, view), str(directory)


def _trusted(ledger: Ledger, checked: bool) -> tuple[str, tuple[dict[str, int], dict[str, int]]]:
    """(what vouches for the directory: "sealed", "journal" or "", :meth:`Ledger.census`) under
    the lock; a ledger neither vouches for is checked (every row unless ``checked`` before the
    lock) before its census is trusted."""
    with contextlib.suppress(sqlite3.DatabaseError):  # damaged: the checks below say how
        census = ledger.census()
        if seal.holds(ledger, census[0]):  # checked when its last session ended, untouched since
            return "sealed", census
        if journal.holds(ledger, census[0]):  # checked when the crashed session began, only it changed it since
            return "journal", census
    integrity.verify(ledger.db, ledger.directory / LEDGER_NAME, thorough=not checked)
    return "", ledger.census()


def _execute(
    campaign: spec.Campaign,
    ledger: Ledger,
    lock: DirectoryLock,
    opts: Options,
    command: str,
    pool: ExecutorHandle | None,
    census: tuple[dict[str, int], dict[str, int]] | None = None,
    view: live_view.LiveView | None = None,
) -> Outcome:
    """Run what the ledger has left on ``pool`` (see :func:`_early_pool`) or on the executor
    the options name; record the session and its end; seal the directory when the session ended
    cleanly (:mod:`.seal`). ``census``: :meth:`Ledger.census` if the caller read it since the last change;
    ``view``: the live view, told the progress and every committed run."""
    ledger.start_session(command)
    c, counts = census or ledger.census()
    total = sum(c.values()) if campaign.guided is None else max(sum(c.values()), campaign.guided.max_runs())
    progress = Progress(
        campaign.name, total, counts, stream=opts.stream, interval_s=opts.progress_interval_s, publish=lock.publish
    )
    real = not campaign.rig_info.simulated
    out = Outcome()
    reason = "error"
    if campaign.guided is None and not (c.get("planned", 0) or c.get("claimed", 0)):
        if view:
            view.ended(progress)
        progress.close()  # nothing left to run: no executor to open
        ledger.end_session("finished")
        _seal(ledger, opts, c)
        out.counts = counts
        return out
    seal.clear(ledger)
    journal.begin(ledger, c)  # settled and checked: from here on only this session changes it
    try:
        with (
            StopSignals() as signals,
            (
                contextlib.nullcontext(pool)
                if pool is not None
                else open_executor(
                    real_rig=real,
                    workers=opts.workers,
                    url=opts.executor,
                    lock_fd=lock.fd,
                    signals=opts.live is not None,
                )
            ) as handle,
        ):
            scheduler = Scheduler(
                campaign,
                ledger,
                executor=handle,
                batch_size=1 if real else opts.batch_size,
                progress=progress,
                signals=signals,
                view=view,
            )
            if campaign.guided is None:
                out = scheduler.run()
            else:  # rounds: the procedure proposes, the scheduler runs
                out = guided_run.execute(campaign, ledger, scheduler.run, signals)
        reason = (
            "abandoned"
            if out.abandoned
            else "interrupted"
            if out.interrupted
            else "stopped"
            if out.stop_reason
            else "finished"
        )
    finally:
        if view:
            view.ended(progress)
        progress.close()
        with contextlib.suppress(LedgerWriteError):  # a full disk: the session's end is not recorded
            ledger.end_session(reason)
        fsync_dir(ledger.directory)
    if reason != "abandoned":  # abandoned batches' workers may still write (the journal stays)
        _seal(ledger, opts)
    return out


def _seal(ledger: Ledger, opts: Options, counts: dict[str, int] | None = None) -> None:
    """At a clean end: close the session journal, quarantine temporary logs a crash left (no batch
    runs now), and seal the directory for the next ``resume`` if every check passes (:mod:`.seal`);
    say so if one fails. A full disk leaves it unsealed."""
    with contextlib.suppress(LedgerWriteError):
        kept = journal.end(ledger)
        if seal.seal(ledger, counts) or (recovery.sweep(ledger) and seal.seal(ledger)):
            return
        if kept and not ledger.counts().get("claimed", 0):  # the resume after a crash left these checks to now
            print(
                f"{ledger.directory}: the end-of-session check did not pass (a log missing, a published log "
                "its row does not record, or a ledger check): not sealed; the next `labrunner resume` "
                "checks and settles everything",
                file=opts.stream or sys.stderr,
            )
