"""The three campaign operations behind ``labrunner run``, ``resume`` and ``status``.

``start`` validates the whole campaign (every point) before it creates anything, refuses a
directory that already holds a campaign, creates the directory, takes its lock, writes the
ledger atomically and runs. ``resume`` takes the lock (a dead runner's lock is taken over),
refuses a campaign whose file changed what would run, settles what a crash left behind
(:mod:`labrunner.campaign.recovery`) and runs what is left. ``status`` only reads.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sqlite3
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from labrunner.campaign import dry_run, guided_run, integrity, plan_inputs, recovery, spec
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


@dataclass(frozen=True)
class Options:
    """How to execute: process-pool size or Dask address, batch size, where progress goes."""

    workers: int | None = None
    executor: str | None = None
    batch_size: int | None = None
    stream: TextIO | None = None
    progress_interval_s: float = 5.0


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
    tmp = directory / f".{CAMPAIGN_COPY}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, directory / CAMPAIGN_COPY)


def start(file: str | Path, out: str | Path | None, opts: Options, *, dry: bool = False) -> tuple[Outcome | None, str]:
    """``labrunner run``: validate everything, then create the campaign directory and run it."""
    check_executor_url(opts.executor, reach=False)
    campaign = spec.load(file)
    if out is not None and not str(out).strip():
        raise InvalidParameter("--out", f"must be a path, got {str(out)!r}")
    directory = Path(out) if out is not None else default_directory(campaign)
    if dry:
        return None, _dry_run(campaign, directory, opts)
    with _early_pool(campaign, opts) as pool:
        points, checksum = spec.plan(campaign)
        _check_new_directory(directory, campaign.name, checksum)
        check_executor_url(opts.executor)  # reached before the directory exists
        directory.mkdir(parents=True, exist_ok=True)
        with DirectoryLock(directory, "run") as lock:
            _check_new_directory(directory, campaign.name, checksum)  # again, now that nobody else can create it
            meta = {
                "campaign": campaign.name,
                "campaign_file": campaign.source,
                "campaign_path": str(Path(file).resolve()),
                "plan_checksum": checksum,
                plan_inputs.META_KEY: plan_inputs.digest(campaign),
                "points": str(len(points)),
                "rig": campaign.rig,
                REAL_RIG: "1" if not campaign.rig_info.simulated else "0",
                "created_at": repr(time.time()),
                "created_by": f"labrunner {__version__} on {socket.gethostname()}",
                **({"guided": campaign.guided.name} if campaign.guided is not None else {}),
            }
            points_rows = ((p.seq, p.id, p.parameters, p.batch_key) for p in points)
            ledger = Ledger.create(directory, meta=meta, points=points_rows)
            del points, points_rows
            _write_copy(directory, campaign.source)  # the ledger exists first: it is what marks the campaign
            (directory / RUNS_DIR).mkdir(exist_ok=True)
            with ledger:
                return _execute(campaign, ledger, lock, opts, "run", pool), str(directory)


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
    return text


def _early_pool(
    campaign: spec.Campaign, opts: Options, lock_fd: int | None = None
) -> contextlib.AbstractContextManager[ExecutorHandle | None]:
    """The local process pool of a simulated campaign, forked before the slow part of starting
    (validating every point, settling a crash) so that its workers load the engine meanwhile, on
    the other cores; None for a real rig or Dask, whose executor :func:`_execute` opens itself
    once the campaign is known to be good."""
    if opts.executor or not campaign.rig_info.simulated:
        return contextlib.nullcontext()
    return open_executor(real_rig=False, workers=opts.workers, url=None, lock_fd=lock_fd)


def _check_unchanged(ledger: Ledger) -> spec.Campaign:
    """The stored campaign; refuse if it, or its original file, plans differently.

    When the plan's inputs (file, rig file, code: :mod:`.plan_inputs`) are those stored at ``run``,
    the plan is the stored one and the ledger's ids were checked against their creation checksum
    on opening (a ledger that keeps none is re-planned); otherwise the campaign is re-planned (0.2–1 ms a point) and compared."""
    meta = ledger.meta()
    lacking = [k for k in ("campaign_file", "campaign_path", "plan_checksum") if k not in meta]
    if lacking:
        raise integrity.damaged(ledger.directory / LEDGER_NAME, f"keeps no {', '.join(lacking)} to resume from")
    source_path = Path(meta["campaign_path"])
    campaign = spec.from_text(meta["campaign_file"], source_path=source_path)
    stored = meta.get(plan_inputs.META_KEY)
    if stored is None or "ids_checksum" not in meta or plan_inputs.digest(campaign) != stored:
        _check_replanned(ledger, campaign, meta["plan_checksum"])
    if source_path.is_file():
        text = source_path.read_text(encoding="utf-8")
        if text != meta["campaign_file"]:
            try:
                edited = spec.from_text(text, source_path=source_path)
                same = stored is not None and plan_inputs.digest(edited) == stored
                if not same:
                    same = spec.plan(edited)[1] == meta["plan_checksum"]
            except Exception:  # an edit that no longer even validates is an edit
                same = False
            if not same:
                raise CampaignError(
                    f"{source_path} was edited since this campaign was planned (its grid or run settings differ); "
                    f"restore it to resume, or run the edited file as a new campaign with --out"
                )
    return campaign


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
    """``labrunner resume``: settle a crash, then run every point that is not terminal."""
    directory = Path(directory)
    check_executor_url(opts.executor, reach=False)
    # a missing, foreign or damaged ledger: exit 2 before the lock file is made (every row is read
    # here once; under the lock only the checks that read no row are repeated: ~6 s less at 10^6)
    with Ledger.open_readonly(directory):
        pass
    runs = directory / RUNS_DIR
    if runs.exists() and not runs.is_dir():
        raise CampaignError(
            f"{runs} is a file, not the directory of the campaign's run logs: move it away, then resume"
        )
    check_executor_url(opts.executor)
    stream = opts.stream or sys.stderr
    with DirectoryLock(directory, "resume") as lock, Ledger.open(directory, verify=False) as ledger:
        integrity.verify(ledger.db, ledger.directory / LEDGER_NAME, thorough=False)
        if lock.took_over:
            print(f"took over the stale lock of {lock.took_over.describe()}", file=stream)
        campaign = _check_unchanged(ledger)
        counts = ledger.counts()
        idle = not (counts.get("planned", 0) or counts.get("claimed", 0) or (retry_failed and counts.get("failed", 0)))
        # a finished campaign needs no workers: forking a pool only to wait for its shutdown cost ~1 s
        early = contextlib.nullcontext() if idle and campaign.guided is None else _early_pool(campaign, opts, lock.fd)
        with early as pool:  # its workers load while a crash is settled
            _write_copy(ledger.directory, ledger.meta()["campaign_file"])
            report = recovery.recover(ledger)
            print(f"resume {directory}: {report.describe()}", file=stream)
            if retry_failed:
                failed = [r["id"] for r in ledger.rows(("failed",))]
                ledger.replan(failed)
                print(f"retrying {len(failed)} failed point(s)", file=stream)
            return _execute(campaign, ledger, lock, opts, "resume", pool), str(directory)


def _execute(
    campaign: spec.Campaign,
    ledger: Ledger,
    lock: DirectoryLock,
    opts: Options,
    command: str,
    pool: ExecutorHandle | None,
) -> Outcome:
    """Run what the ledger has left on ``pool`` (see :func:`_early_pool`) or on the executor
    the options name; record the session and its end."""
    ledger.start_session(command)
    c = ledger.counts()
    total = sum(c.values()) if campaign.guided is None else max(sum(c.values()), campaign.guided.max_runs())
    progress = Progress(
        campaign.name,
        total,
        ledger.by_outcome(),
        stream=opts.stream,
        interval_s=opts.progress_interval_s,
    )
    real = not campaign.rig_info.simulated
    out = Outcome()
    reason = "error"
    if campaign.guided is None and not (c.get("planned", 0) or c.get("claimed", 0)):
        progress.close()  # nothing left to run: no executor to open
        ledger.end_session("finished")
        out.counts = ledger.by_outcome()
        return out
    try:
        with (
            StopSignals() as signals,
            (
                contextlib.nullcontext(pool)
                if pool is not None
                else open_executor(real_rig=real, workers=opts.workers, url=opts.executor, lock_fd=lock.fd)
            ) as handle,
        ):
            scheduler = Scheduler(
                campaign,
                ledger,
                executor=handle,
                batch_size=1 if real else opts.batch_size,
                progress=progress,
                signals=signals,
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
        progress.close()
        with contextlib.suppress(LedgerWriteError):  # a full disk: the session's end is not recorded
            ledger.end_session(reason)
        fsync_dir(ledger.directory)
    return out
