"""What runs in a worker process (or a Dask worker, or in-process for a real rig): one batch.

:func:`execute_batch` loads the rig, runs the batch through :func:`labrunner.engine.run_batch`
and *publishes* each run's MCAP atomically — written under a temporary name in ``DIR/runs/``,
fsynced, renamed to ``runs/<point_id>.mcap``, the directory fsynced — before it returns the
small summaries the parent commits to the ledger. The ordering is the crash-safety argument: a
row is never terminal without its published file; a published file without a terminal row is
settled by :mod:`labrunner.campaign.recovery` on resume. Signals never leave the worker, so the
parent's memory does not grow with the number of runs.
"""

from __future__ import annotations

import functools
import os
import secrets
import socket
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from labrunner import safefs
from labrunner.campaign import live
from labrunner.campaign.ledger import RunRecord, fsync_dir
from labrunner.errors import CampaignError, RigError, os_reason
from labrunner.run_identity import fingerprint

RUNS_DIR = "runs"
TMP_PREFIX = ".tmp-"
_FSYNC_THREADS = 8
_FSYNC_GROUP = 16  # logs fsynced by one thread task, one after the other


@dataclass(frozen=True)
class RunTask:
    """One point of a batch: id, attempt number, grid parameters, resolved configuration, seed."""

    point_id: str
    attempt: int
    parameters: Mapping[str, Any]
    config: Mapping[str, Any]
    seed: int


@dataclass(frozen=True)
class BatchTask:
    """A batch of compatible points (same rig, f_s [Hz], duration [s], controller kind)."""

    directory: str  # the campaign directory (absolute; shared with remote workers)
    campaign: str
    campaign_source: str  # the campaign file, attached to every log
    rig: str
    rig_search: tuple[str, ...]
    rig_safety: Mapping[str, Any]
    fs: float
    duration: float
    runs: tuple[RunTask, ...]
    samples_hz: float | None = None  # [logging] samples_hz: thin the logs' per-sample channel (None: full rate)
    precision: str = "float64"  # [logging] precision: "float32" rounds every logged signal to float32
    live_at: live.Address | None = None  # where the worker reports the ticks done (labrunner.campaign.live)
    metadata: Mapping[str, Any] = field(default_factory=dict)  # the campaign's [metadata]: each log's record
    rig_link: Mapping[str, str] = field(default_factory=dict)  # --port etc. instead of the rig file's (run, resume)


@dataclass
class BatchResult:
    """Per-run records to commit, and whether the rig asked to stop the campaign (RigError)."""

    records: list[RunRecord] = field(default_factory=list)
    stop: str = ""  # non-empty: the reason to stop the campaign
    unrun: bool = False  # the runner's stop level ended the batch before it ran to the end: nothing published
    failure_limit: int = 0  # the rig's max_consecutive_failures: points in a row failed that stop it (0: none)


def final_path(point_id: str) -> str:
    """Log path of a point, relative to the campaign directory."""
    return f"{RUNS_DIR}/{point_id}.mcap"


def _load_rig(task: BatchTask):
    """The rig and its validated rig file, whose JSON form every run log keeps as its ``rig`` record."""
    from labrunner.rigs import registry
    from labrunner.rigs.config import load_rig_config

    config = load_rig_config(task.rig, search=task.rig_search, link=task.rig_link)
    return registry.load_rig(config), config.to_dict()


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_all(paths: list[Path]) -> None:
    for path in paths:
        with safefs.naming(path):
            _fsync(path)


def _metadata(task: BatchTask, run: RunTask, host: str, start_time: float) -> dict[str, dict[str, Any]]:
    """A run's own log records (the rig record is shared by the batch: :func:`_publish_all`)."""
    return {
        "run": {
            "campaign": task.campaign,
            "point_id": run.point_id,
            "attempt": run.attempt,
            "seed": run.seed,
            "rig": task.rig,
            "duration": task.duration,
            "host": host,
            "pid": os.getpid(),
            "start_time": start_time,  # [s since 1970] the batch's start: sample k's log time is this + k / fs
        },
        "config": dict(run.config),
        "parameters": dict(run.parameters),
        **({"metadata": dict(task.metadata)} if task.metadata else {}),
    }


def execute_batch(task: BatchTask, run_batch: Callable[..., Sequence[Any]] | None = None) -> BatchResult:
    """Run ``task`` and publish its logs; never raises for a run's own failure.

    ``run_batch`` defaults to :func:`labrunner.engine.run_batch`, or to the rig's
    ``run_on_device`` when its loop runs on the device (tests inject fakes). A rig that
    cannot be opened asks the parent to stop and leaves the points claimed (nothing ran; ``resume``
    reruns them). A :class:`~labrunner.errors.RigError` during the runs marks the batch failed,
    publishing the logs up to the failure when the engine attached them (``exc.results``); the
    campaign goes on when the rig's ``recover()`` finds the device answering a fresh handshake in
    its safe state, else the parent stops (architecture: "stop-campaign"). ``failure_limit`` tells
    the parent the rig's ``max_consecutive_failures``. Any other exception marks the batch's
    points failed with the message (they have no log) and the campaign goes on. The ticks done go
    to the runner's live channel (:mod:`labrunner.campaign.live`) as they pass; when the runner
    stops (Ctrl-C) the batch ends there unrun (``unrun``: nothing published, the rig in its safe state).
    """
    host, pid = socket.gethostname(), os.getpid()
    out = BatchResult()
    report = live.hook(task.live_at)
    try:
        if report is not None:
            report(0)  # taken: no longer queued
        return _execute(task, out, report, run_batch, host, pid)
    except live.Stopped:
        out.records, out.unrun = [], True
        return out


def _execute(
    task: BatchTask,
    out: BatchResult,
    report: Callable[[int], None] | None,
    run_batch: Callable[..., Sequence[Any]] | None,
    host: str,
    pid: int,
) -> BatchResult:
    """:func:`execute_batch` once the batch is taken: load the rig, run, publish."""
    ticks = round(task.fs * task.duration)
    t0, start_time = time.perf_counter(), time.time()
    try:
        rig, rig_record = _load_rig(task)
    except Exception as exc:  # no rig, no campaign: stop; nothing ran, so the points stay claimed for resume
        out.stop = f"rig {task.rig!r} cannot be opened: {type(exc).__name__}: {exc}"
        return out
    parameters = getattr(rig, "parameters", None)  # a remote rig file's: max_consecutive_failures
    out.failure_limit = int(parameters.get("max_consecutive_failures", 0)) if isinstance(parameters, Mapping) else 0
    try:
        with rig:
            try:
                results = list(
                    (
                        run_batch
                        or _batch_runner(rig, report, live.watcher(task.live_at, ticks, task.fs), len(task.runs))
                    )(
                        [r.config for r in task.runs],
                        rig,
                        fs=task.fs,
                        duration=task.duration,
                        seeds=[r.seed for r in task.runs],
                        rig_safety=task.rig_safety,
                    )
                )
            except RigError as exc:
                exc.after = _recover(rig)
                raise
    except live.Stopped:
        raise
    except RigError as exc:  # the engine hands over the failed runs' logs up to the failure when it has them
        after = getattr(exc, "after", "")  # None: the device is back in its safe state, the campaign goes on
        if after is not None:
            out.stop = f"rig {task.rig!r}: {exc}" + (f"; {after}" if after else "")
        partial = getattr(exc, "results", None)
        if not partial:
            return _failed(task, out, f"rig {task.rig!r}: {exc}", host, pid)
        results = list(partial)
    except Exception as exc:  # bad configuration or a crash: the batch's points fail, the campaign goes on
        detail = traceback.format_exception_only(type(exc), exc)[-1].strip()
        return _failed(task, out, detail, host, pid)
    diagnostics = rig.diagnostics() if hasattr(rig, "diagnostics") else None  # a real rig's link record (B = 1)
    if hasattr(rig, "device_clock") and len(results) == 1 and results[0].device_clock is None:  # a host loop
        results[0].device_clock = rig.device_clock()
    engine_s = (time.perf_counter() - t0) / max(len(task.runs), 1)
    try:
        _publish_all(task, results, out, engine_s, host, pid, rig_record, start_time, diagnostics)
    except Exception as exc:  # re-raised as a plain, picklable error: the parent stops the campaign
        raise CampaignError(_publish_error(exc)) from None
    return out


def _recover(rig: Any) -> str | None:
    """After a RigError: None when the device answered a fresh handshake in its safe state (the
    point fails, the campaign goes on); else why the campaign stops ("" for a rig that has no way
    to check itself: the failure alone says it)."""
    recover = getattr(rig, "recover", None)
    if recover is None:
        return ""
    try:
        recover()
    except RigError as exc:
        return str(exc)
    return None


def _publish_error(exc: Exception) -> str:
    """One line naming the file a batch's logs failed on, and why (a full disk: how to go on)."""
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"cannot write the run log {exc.filename}: {os_reason(exc, advice=False)}"  # the stop says: resume
    return f"publishing the run logs failed: {type(exc).__name__}: {exc}"


def _batch_runner(
    rig: Any, report: Callable[[int], None] | None, watch: Callable[..., None] | None = None, runs: int = 1
) -> Callable[..., Sequence[Any]]:
    """How a batch of ``runs`` runs on ``rig``: the engine's loop (telling ``report`` the ticks
    done and ``watch`` its representative run's samples, :func:`live.representative`), or the rig's
    own for a loop on the device (a real rig, in the parent's process: no live channel)."""
    from labrunner import engine

    if getattr(rig, "loop", "host") == "device":
        return lambda points, rig, **kw: rig.run_on_device(points, **kw)
    return functools.partial(engine.run_batch, progress=report, watch=watch, watch_run=live.representative(runs))


def _publish_all(
    task: BatchTask,
    results: list[Any],
    out: BatchResult,
    engine_s: float,
    host: str,
    pid: int,
    rig: Mapping[str, Any],
    start_time: float,
    diagnostics: Mapping[str, Any] | None = None,
) -> None:
    """Write every log under a temporary name, fsync them concurrently while the next ones are
    written (groups of :data:`_FSYNC_GROUP` per thread task, so that the writing thread hands work
    over once per group rather than per file; one journal flush for many files instead of one
    each), rename them into place, fsync the directory once. What the logs
    share (rig record, campaign file, schemas) is encoded once for the batch. A real rig's
    ``diagnostics`` record (docs/protocol.md § Diagnostics), or a device-loop run's own
    (``RunResult.diagnostics``, docs/device-loop.md), is the log's ``diagnostics`` metadata record,
    apart from its outcome record (one shape for every run), and the ledger's (:func:`ledger_outcome`)."""
    from labrunner.logs import BatchPrefixes, write_run

    runs_dir = Path(task.directory) / RUNS_DIR
    samples_hz = None if task.samples_hz is None or task.samples_hz >= task.fs else task.samples_hz
    # rig: kind, parameters, limits, noise, faults, safety as the rig file gave them
    prefixes = BatchPrefixes(task.fs, {"rig": dict(rig)}, {"campaign.toml": task.campaign_source.encode()}, samples_hz)
    written, synced, group = [], [], []
    token = secrets.token_hex(4)  # with the pid and the point id, unique among the batches that may write at once
    with ThreadPoolExecutor(max_workers=_FSYNC_THREADS) as syncer:
        for i, run in enumerate(task.runs):
            result, results[i] = results[i], None  # free each run's signals as soon as it is written
            t1 = time.perf_counter()
            tmp = runs_dir / f"{TMP_PREFIX}{run.point_id}-{pid}-{token}.mcap"
            metadata = _metadata(task, run, host, start_time)
            metadata["metrics"] = dict(result.metrics)
            outcome = result.outcome.as_dict()
            record = getattr(result, "diagnostics", None) or diagnostics  # a device loop's record is per run
            if record is not None:
                metadata["diagnostics"] = dict(record)
            signals, channels = with_device_clock(result)
            float32 = signals if task.precision == "float32" else getattr(result, "float32_signals", ())
            with safefs.naming(tmp):
                write_run(
                    tmp,
                    metadata=metadata,
                    signals=signals,
                    outcome=outcome,
                    prefix=prefixes.get(list(signals), channels, float32),
                    start_time=start_time,
                )
            written.append((run, tmp, ledger_outcome(outcome, record), dict(result.metrics), time.perf_counter() - t1))
            group.append(tmp)
            if len(group) == _FSYNC_GROUP or i == len(task.runs) - 1:  # fsynced while the next ones are written
                synced.append(syncer.submit(_fsync_all, group))
                group = []
        t2 = time.perf_counter()
        for future in synced:
            future.result()
        for run, tmp, *_ in written:
            safefs.replace(tmp, runs_dir / f"{run.point_id}.mcap")
    fsync_dir(runs_dir)  # every rename durable before any row is committed
    # each log as published (after its rename, which sets its ctime): analyse needs not read it to know it
    fingerprints = [fingerprint(runs_dir / f"{run.point_id}.mcap") for run, *_ in written]
    publish_s = (time.perf_counter() - t2) / max(len(written), 1)
    now = time.time()
    for (run, _, outcome, metrics, write_s), stat in zip(written, fingerprints):
        out.records.append(
            RunRecord(
                point_id=run.point_id,
                outcome=outcome["status"],
                outcome_record=outcome,
                metrics=metrics,
                log_path=final_path(run.point_id),
                host=host,
                pid=pid,
                finished_at=now,
                engine_s=engine_s,
                write_s=write_s,
                publish_s=publish_s,
                log_fingerprint=stat,
            )
        )


def ledger_outcome(outcome: Mapping[str, Any], diagnostics: Mapping[str, Any] | None) -> dict[str, Any]:
    """The outcome as the ledger stores it (``outcome_json``): a real rig's ``diagnostics`` record
    under ``diagnostics``, where ``status`` finds a device loop's law check and the rig's timing in
    SQL (:mod:`labrunner.campaign.rig_timing`). Internal: the log's outcome record and the results
    API have one shape for every run, the diagnostics apart."""
    return {**outcome, "diagnostics": dict(diagnostics)} if diagnostics else dict(outcome)


def with_device_clock(result: Any) -> tuple[dict[str, Any], Mapping[str, Any]]:
    """A run's signals and channels to log: a real device's timestamps (``device_clock``) added as
    the signal ``t_device`` [s] (role *signal*; NaN where a sample has none), the log time staying
    the tick grid start + k/f_s."""
    clock = getattr(result, "device_clock", None)
    if clock is None:
        return result.signals, result.channels
    n = result.n_samples
    t = np.full(n, np.nan)
    t[: min(n, len(clock))] = np.asarray(clock, float)[:n]
    channels = dict(result.channels)
    channels["signals"] = [*channels.get("signals", []), "t_device"]
    channels["units"] = {**channels.get("units", {}), "t_device": "s"}
    return {**result.signals, "t_device": t}, channels


def _failed(task: BatchTask, out: BatchResult, message: str, host: str, pid: int) -> BatchResult:
    now = time.time()
    for run in task.runs:
        out.records.append(
            RunRecord(
                point_id=run.point_id,
                outcome="failed",
                outcome_record={"status": "failed", "message": message},
                metrics={},
                log_path=None,
                host=host,
                pid=pid,
                finished_at=now,
            )
        )
    return out
