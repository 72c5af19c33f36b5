"""Scheduling a campaign's planned points onto an executor, committing each finished run.

Points that can share a lockstep batch (same rig, f_s, duration and non-numeric choices such as
the controller kind — see :mod:`labrunner.campaign.checks`) are cut into batches in grid order
and submitted through the :class:`concurrent.futures.Executor` interface:

- a local process pool (default; ``--workers N``, default all cores), workers forked, ignoring
  SIGINT (the parent decides what Ctrl-C means) and killed if the parent dies (``PR_SET_PDEATHSIG``);
- a Dask distributed cluster (``--executor tcp://HOST:PORT``: ``Client(address).get_executor()``);
  its workers must see the campaign directory (shared file system);
- in-process, one run at a time, for a real rig.

A batch's points are claimed in one transaction when it is submitted; each run's row is
committed when its batch returns (the worker has published the logs by then). Ctrl-C (or
SIGTERM) once: no new batches, batches not yet started are unclaimed, running ones finish and are
committed. Twice: running batches are abandoned, their points stay claimed and ``resume`` settles
them. Either way the ledger is consistent and the rig is left in its safe state.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import math
import multiprocessing
import os
import signal
import time
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

from labrunner.campaign.ledger import Ledger
from labrunner.campaign.progress import Progress
from labrunner.campaign.spec import Campaign
from labrunner.campaign.worker import BatchResult, BatchTask, RunTask, execute_batch
from labrunner.errors import CampaignError, InvalidParameter

BATCH_MEMORY_BYTES = 256 * 2**20  # a batch's signal buffers stay below this
_BYTES_PER_SAMPLE = 8 * 32  # float64 × (generous) number of logged traces per run
# The engine's per-tick cost model, cost(B) ≈ TICK_OVERHEAD_S + B · RUN_TICK_S (motor velocity MFC
# at 200 Hz, one CPU of a loaded 2-core machine: ~130 µs per tick plus ~0.5 µs per run and tick;
# benchmarks/bench_engine.py). A batch is large enough once the fixed part is at most
# TICK_OVERHEAD_SHARE of a tick.
TICK_OVERHEAD_S = 130e-6
RUN_TICK_S = 0.5e-6
TICK_OVERHEAD_SHARE = 0.1
_PR_SET_PDEATHSIG = 1
_STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


@dataclass
class Outcome:
    """How a scheduling session ended."""

    committed: int = 0
    interrupted: bool = False
    abandoned: bool = False
    stop_reason: str = ""
    elapsed_s: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)
    signals: int = 0  # Ctrl-C/SIGTERM received, also one after the last batch began (a guided campaign stops on it)


def batch_size(group_points: int, slots: int, samples: int, requested: int | None = None) -> int:
    """Runs per batch of a group of ``group_points`` compatible points of ``samples`` ticks each.

    Lockstep cost per run is ``(TICK_OVERHEAD_S / B + RUN_TICK_S)`` per tick, so larger batches are
    cheaper per run, up to the size where the fixed part is :data:`TICK_OVERHEAD_SHARE` of a tick,
    and within :data:`BATCH_MEMORY_BYTES`. The group is cut into a multiple of ``slots`` batches
    of equal size, so that every worker has work and none is left running one batch alone at the
    end: 1000 points on 2 workers → 2 batches of 500; 10 000 → 10 of 1000 (the memory budget at
    1000 samples)."""
    if requested is not None:
        return requested
    slots = max(slots, 1)
    by_memory = max(1, BATCH_MEMORY_BYTES // max(samples * _BYTES_PER_SAMPLE, 1))
    by_cost = math.ceil(TICK_OVERHEAD_S / RUN_TICK_S * (1.0 - TICK_OVERHEAD_SHARE) / TICK_OVERHEAD_SHARE)
    largest = min(by_memory, by_cost)
    batches = slots * math.ceil(group_points / (slots * largest))
    return max(1, math.ceil(group_points / batches))


def make_batches(rows: list[Any], slots: int, requested: int | None = None) -> list[tuple[str, list[Any]]]:
    """Cut ledger rows (grid order) into batches of compatible points; deterministic."""
    groups: dict[str, list[Any]] = {}
    for row in rows:
        groups.setdefault(row["batch_key"], []).append(row)
    out = []
    for key, members in groups.items():
        _, fs, duration, *_ = json.loads(key)
        size = batch_size(len(members), slots, round(fs * duration), requested)
        count = math.ceil(len(members) / size)
        if requested is None:  # automatic: equal sizes (differing by one at most), none above size
            cuts = [len(members) * j // count for j in range(count + 1)]
        else:  # as asked, the last batch takes the rest
            cuts = [*range(0, len(members), size), len(members)]
        out += [(key, members[lo:hi]) for lo, hi in zip(cuts, cuts[1:])]
    return out


class InProcessExecutor(Executor):
    """Runs each call in the caller's process at submit time: a real rig, one run at a time."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        future: Future = Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except Exception as exc:
            future.set_exception(exc)
        return future


def _init_worker(lock_fd: int | None) -> None:
    """Pool worker set-up: leave Ctrl-C/SIGTERM to the parent (it lets running batches finish or
    kills the workers), die with the parent, drop the inherited lock descriptor."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)  # blocked by the parent while it forked us
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() == 1:  # the parent died before prctl took effect
        os._exit(1)
    if lock_fd is not None:
        with contextlib.suppress(OSError):
            os.close(lock_fd)


def _preload_worker_modules() -> None:
    """Import what every batch needs (the engine, the log writer) before the pool forks: the
    workers inherit it instead of each importing it again (~0.1–0.2 s CPU per worker)."""
    import labrunner.engine  # noqa: F401
    import labrunner.logs.writer  # noqa: F401


def check_executor_url(url: str | None) -> None:
    """``--executor`` must be a Dask scheduler address."""
    if url is not None and not url.startswith(("tcp://", "tls://", "inproc://")):
        raise InvalidParameter("--executor", f"must be a Dask scheduler address tcp://HOST:PORT, got {url!r}")


@contextlib.contextmanager
def open_executor(
    *, real_rig: bool, workers: int | None, url: str | None, lock_fd: int | None = None
) -> Iterator[tuple[Executor, int]]:
    """The executor for this campaign and its number of parallel slots."""
    if real_rig:
        yield InProcessExecutor(), 1
        return
    if url:
        check_executor_url(url)
        from distributed import Client

        try:
            client = Client(url, timeout=20)
        except OSError as exc:
            raise CampaignError(f"cannot reach the Dask scheduler at {url}: {exc}") from None
        try:
            slots = workers or max(1, sum(client.nthreads().values()))
            yield client.get_executor(pure=False), slots
        finally:
            client.close()
        return
    n = workers or len(os.sched_getaffinity(0))
    _preload_worker_modules()
    pool = ProcessPoolExecutor(
        max_workers=n, mp_context=multiprocessing.get_context("fork"), initializer=_init_worker, initargs=(lock_fd,)
    )
    try:
        yield pool, n
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


class _Signals:
    """SIGINT/SIGTERM → a counter; the second one raises KeyboardInterrupt (abandon)."""

    def __init__(self) -> None:
        self.count = 0
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, frame: Any) -> None:
        self.count += 1
        if self.count >= 2:
            raise KeyboardInterrupt

    def __enter__(self) -> _Signals:
        with contextlib.suppress(ValueError):  # not the main thread: keep the default behaviour
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


class Scheduler:
    """Runs the planned points of an open ledger."""

    def __init__(
        self,
        campaign: Campaign,
        ledger: Ledger,
        *,
        executor: Executor,
        slots: int,
        batch_size: int | None = None,
        progress: Progress | None = None,
        batch_fn: Callable[[BatchTask], BatchResult] = execute_batch,
    ) -> None:
        self.campaign, self.ledger = campaign, ledger
        self.executor, self.slots = executor, slots
        self.requested = batch_size
        self.progress = progress
        self.batch_fn = batch_fn
        self.inflight: dict[Future, list[str]] = {}

    def _task(self, key: str, rows: list[Any]) -> BatchTask:
        _, fs, duration, *_ = json.loads(key)
        c = self.campaign
        runs = []
        for row in rows:
            params = json.loads(row["parameters"])
            config = c.resolve(params)
            config["campaign"]["duration"] = duration
            runs.append(RunTask(row["id"], row["attempts"] + 1, params, config, int(config["campaign"]["seed"])))
        return BatchTask(
            directory=str(self.ledger.directory.resolve()), campaign=c.name, campaign_source=c.source, rig=c.rig_ref,
            rig_search=c.rig_search, rig_safety=dict(c.rig_safety), fs=float(fs), duration=float(duration),
            runs=tuple(runs), samples_hz=c.logging.get("samples_hz"),
        )

    def _submit(self, key: str, rows: list[Any]) -> None:
        task = self._task(key, rows)
        ids = [r.point_id for r in task.runs]
        self.ledger.claim(ids)
        forks = isinstance(self.executor, ProcessPoolExecutor)  # its first submit forks the workers:
        try:  # a Ctrl-C must not reach a worker before its initializer ignores it (it stays pending here)
            if forks:
                signal.pthread_sigmask(signal.SIG_BLOCK, _STOP_SIGNALS)
            try:
                future = self.executor.submit(self.batch_fn, task)
            finally:
                if forks:
                    signal.pthread_sigmask(signal.SIG_UNBLOCK, _STOP_SIGNALS)
        except BaseException:
            if not isinstance(self.executor, InProcessExecutor):
                self.ledger.unclaim(ids)
            raise
        self.inflight[future] = ids
        if self.progress:
            self.progress.started_runs(len(ids))

    def _collect(self, future: Future, out: Outcome) -> None:
        ids = self.inflight.pop(future)
        if future.cancelled():
            self.ledger.unclaim(ids)
            return
        exc = future.exception()
        if exc is not None:  # the worker itself broke (died, could not write): stop, points stay claimed
            out.stop_reason = out.stop_reason or f"a worker failed: {type(exc).__name__}: {exc}"
            return
        result: BatchResult = future.result()
        for record in result.records:
            self.ledger.commit(record)
            out.committed += 1
            if self.progress:
                self.progress.update(record.outcome)
        if result.stop:
            out.stop_reason = out.stop_reason or result.stop

    def run(self) -> Outcome:
        """Run every planned point; returns when done, stopped, or interrupted."""
        out = Outcome()
        t0 = time.monotonic()
        rows = self.ledger.rows(("planned",))
        pending = deque(make_batches(rows, self.slots, self.requested))
        del rows
        in_process = isinstance(self.executor, InProcessExecutor)  # runs at submit: check stop/Ctrl-C after each
        max_inflight = 1 if in_process else max(1, 2 * self.slots)
        with _Signals() as signals:
            try:
                while pending or self.inflight:
                    if signals.count and not out.interrupted:
                        out.interrupted = True
                        self._say("interrupted: finishing the running batches (Ctrl-C again to abandon them)")
                        for f in list(self.inflight):
                            if f.cancel():
                                self._collect(f, out)
                    if out.interrupted or out.stop_reason:
                        pending.clear()
                    while pending and len(self.inflight) < max_inflight:
                        self._submit(*pending.popleft())
                    if not self.inflight:
                        continue
                    done, _ = wait(list(self.inflight), timeout=0.25, return_when=FIRST_COMPLETED)
                    for future in done:
                        self._collect(future, out)
                    if self.progress:
                        self.progress.tick()
            except KeyboardInterrupt:
                out.interrupted = out.abandoned = True
                for future in self.inflight:
                    future.cancel()
                self.inflight.clear()
            out.signals = signals.count
        out.elapsed_s = time.monotonic() - t0
        out.counts = self.ledger.by_outcome()
        return out

    def _say(self, message: str) -> None:
        if self.progress:
            self.progress.write(message)


def kill_pool_workers() -> None:
    """Abandon running batches: kill this process's pool workers (their points stay claimed)."""
    for child in multiprocessing.active_children():
        child.kill()
