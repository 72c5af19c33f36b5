"""Scheduling a campaign's planned points onto an executor, committing each finished run.

Points that can share a lockstep batch (same rig, f_s, duration and non-numeric choices such as
the controller kind — see :mod:`labrunner.campaign.checks`) are cut into batches (strided over
the grid: :func:`make_batches`; points that differ only in a controller's per-run choices, the plate
MFC's input law, share batches where that makes fewer of them) and submitted to an executor (:mod:`labrunner.campaign.executors`:
a local process pool, a Dask cluster, or in-process for a real rig).

A batch's points are claimed in one transaction when it is submitted, and its runs' rows are
committed in one when it returns (the worker has published the logs by then). While batches
run, the share of their ticks done (:mod:`labrunner.campaign.live`) goes to the progress as
run-equivalents in flight, so its rate and ETA hold from the first second.

Supervision — the loop never blocks longer than :data:`POLL_S` and never hangs:

- Ctrl-C (or SIGTERM) once: no new batches; on a process pool or a Dask cluster every batch
  handed to it stops (queued ones before they start — on Dask cancelled too —, running ones at
  their next progress report, ≤ 1 % of their ticks: :mod:`labrunner.campaign.live`), the rig put
  in its safe state, nothing published, and their points go back to ``planned`` — a second or
  so, whatever the batch size. A batch whose worker did not get the stop (a Dask worker that
  joined later) finishes and is committed, as does a real rig's one run; all within a bound the
  runner prints (twice their expected time + :data:`GRACE_S`), after which they are abandoned. Twice: whatever still
  runs is abandoned at once. The signal handler only counts; nothing is raised into a lock or
  a transaction.
- A dead worker (``BrokenProcessPool``), a lost Dask worker or scheduler, a worker that cannot
  publish: stop submitting (queued batches are not started), the same bounded wait for the
  running ones (a dead pool worker takes every running batch with it: abandoned at once), then
  the session ends with the reason. A worker that is alive but
  makes no progress (stopped with SIGSTOP, hung) is a dead one too: a started batch whose live
  tick count has not moved for :func:`stall_limit_s` (at least :data:`STALL_S`) is reported and
  the running batches abandoned at once (pool workers get SIGKILL, which also ends a stopped one).

Abandoned batches' points stay claimed; ``resume`` settles them (a log published before the
abandonment is accepted). Either way the ledger is consistent and the rig is left in its safe state.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import signal
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, BrokenExecutor, Executor, Future, wait
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

from labrunner.campaign.executors import STOP_SIGNALS, ExecutorHandle
from labrunner.campaign.grid import canonical_json
from labrunner.campaign.ledger import Ledger, LedgerWriteError
from labrunner.campaign.live import QUEUED, START_NOTHING, STOP_RUNNING, RunSignals, representative
from labrunner.campaign.live_view import LiveView
from labrunner.campaign.progress import Progress
from labrunner.campaign.spec import Campaign
from labrunner.campaign.worker import BatchResult, BatchTask, RunTask, execute_batch
from labrunner.interrupts import FirstPressStops

BATCH_MEMORY_BYTES = 256 * 2**20  # a batch's signal buffers stay below this
_BYTES_PER_SAMPLE = 8 * 32  # float64 × (generous) number of logged traces per run
POLL_S = 0.25  # how often the loop looks at signals, deadlines and results [s]
PROBE_S = 2.0  # how often the executor's health is probed [s]
GRACE_S = 10.0  # beyond the running batches' own duration, before they are abandoned [s]
STALL_S = 30.0  # a started batch whose ticks do not move for this long (or its expected time) is stalled [s]
# The engine's per-tick cost model, cost(B) ≈ TICK_OVERHEAD_S + B · RUN_TICK_S (motor velocity MFC
# at 200 Hz, one CPU of a loaded 2-core machine: ~130 µs per tick plus ~0.5 µs per run and tick;
# benchmarks/bench_engine.py). A batch is large enough once the fixed part is at most
# TICK_OVERHEAD_SHARE of a tick.
TICK_OVERHEAD_S = 130e-6
RUN_TICK_S = 0.5e-6
TICK_OVERHEAD_SHARE = 0.1


_T = TypeVar("_T")

#: Why a campaign stopped when a worker process died, whether a batch was running or about to be sent.
_WORKER_DIED = "a worker process died (killed, or out of memory?); the running batches were abandoned"


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
    complete: bool = False  # nothing is left to run (every point terminal; a guided procedure finished)


def stall_limit_s(batch: _Batch, ticks: int) -> float:
    """How long a started batch's live ticks may stand still at ``ticks`` before its worker counts
    as dead [s]: :data:`STALL_S`, or ten times the cost model's time between two progress reports
    if longer (the engine reports ``PROGRESS_CALLS`` times a batch); once its last tick is done,
    four times that while its logs are written and fsynced (nothing reports progress then)."""
    from labrunner.engine import PROGRESS_CALLS

    between = 10.0 * batch.ticks * (TICK_OVERHEAD_S + len(batch.ids) * RUN_TICK_S) / PROGRESS_CALLS
    limit = max(STALL_S, between)
    return 4.0 * limit if ticks >= batch.ticks else limit


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
    """Cut ledger rows (grid order) into batches of compatible points; deterministic.

    Automatic sizes are equal (differing by one at most) and *strided*: batch j of a group of
    ``count`` takes its points j, j + count, j + 2·count, … so that every batch samples the whole
    group. Runs cost more or less by where they lie in the grid (a run that aborts early leaves
    a shorter log), and contiguous batches would hand one worker the costly end of a grid while
    the other idles. A requested size cuts the group in grid order, the last batch taking the rest.
    Groups whose keys differ only in their per-run choices are cut as one where that makes fewer
    batches (:func:`merges`); such a mixed batch carries the key they share (:func:`family`).
    """
    groups: dict[str, list[int]] = {}
    for at, row in enumerate(rows):
        groups.setdefault(row["batch_key"], []).append(at)
    return [(key, [rows[at] for at in members]) for key, members in _batches(groups.items(), slots, requested)]


def planned_batches(ledger: Ledger, slots: int, requested: int | None = None) -> list[tuple[str, Sequence[int]]]:
    """:func:`make_batches` of the ledger's planned rows, as the rows' ``seq`` (grid positions):
    the same batches in the same order, from the planned-points index alone
    (:meth:`~labrunner.campaign.ledger.Ledger.planned_seqs`: 8 bytes a point); the scheduler reads
    a batch's rows as it submits it."""
    return _batches(ledger.planned_seqs(), slots, requested)


def family(key: str) -> str:
    """What the runs of a batch must share: ``key`` without its per-run choices, the sixth element
    of a key that has them (:func:`labrunner.campaign.checks.batch_key_of`); a five-element key as it is."""
    parts = json.loads(key)
    return canonical_json(parts[:5]) if len(parts) > 5 else key


def merges(key: str, sizes: Sequence[int], slots: int, requested: int | None = None) -> bool:
    """Whether groups of ``sizes`` points of one :func:`family` (``key``) are cut as one: only where
    that makes fewer batches than each group cut alone at the merged batches' size. A mixed batch
    computes every law it holds for each of its rows, so groups that already fill the workers stay
    apart (paper 2 Fig. 8: four laws × 8 points on 2 workers, 8 batches of 4 either way), while
    Table 3's four laws of one point each run as 2 batches of 2 rather than 4 of 1."""
    _, fs, duration, *_ = json.loads(key)
    size = batch_size(sum(sizes), slots, round(fs * duration), requested)
    return math.ceil(sum(sizes) / size) < sum(math.ceil(n / size) for n in sizes)


def _batches(
    groups: Iterable[tuple[str, Sequence[int]]], slots: int, requested: int | None
) -> list[tuple[str, Sequence[int]]]:
    """The batches of groups of grid positions (by batch key, in the order of their first point),
    families in the order of their first group: a family's groups merged where :func:`merges`."""
    families: dict[str, list[tuple[str, Sequence[int]]]] = {}
    for key, members in groups:
        families.setdefault(family(key), []).append((key, members))
    out: list[tuple[str, Sequence[int]]] = []
    for shared, parts in families.items():
        if len(parts) > 1 and merges(shared, [len(m) for _, m in parts], slots, requested):
            parts = [(shared, sorted(itertools.chain.from_iterable(m for _, m in parts)))]
        for key, members in parts:
            out += _cut(key, members, slots, requested)
    return out


def _cut(key: str, members: Sequence[_T], slots: int, requested: int | None) -> list[tuple[str, Sequence[_T]]]:
    """One group's batches (:func:`make_batches`): strided, or in grid order with a requested size."""
    _, fs, duration, *_ = json.loads(key)
    size = batch_size(len(members), slots, round(fs * duration), requested)
    count = math.ceil(len(members) / size)
    if requested is None:
        return [(key, members[j::count]) for j in range(count)]
    return [(key, members[lo : lo + size]) for lo in range(0, len(members), size)]


class StopSignals:
    """SIGINT/SIGTERM → a counter the scheduler polls; nothing is raised, so no lock or transaction
    is ever left half-way. Only while ``interruptible`` (a real rig's run in this process, which
    nothing else can stop) does the second one raise KeyboardInterrupt; the rig's context then
    puts it in its safe state."""

    def __init__(self) -> None:
        self.count = 0
        self.interruptible = False
        self._old: dict[int, Any] = {}

    def _handle(self, signum: int, frame: Any) -> None:
        self.count += 1
        if self.count >= 2 and self.interruptible:
            self.interruptible = False
            raise KeyboardInterrupt

    def __enter__(self) -> StopSignals:
        with contextlib.suppress(ValueError):  # not the main thread: keep the default behaviour
            for sig in STOP_SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, old in self._old.items():
            if self.count and isinstance(old, FirstPressStops):
                old.spend()  # the program winds down from this stop: a later press must not cut it short
            signal.signal(sig, old)


class Scheduler:
    """Runs the planned points of an open ledger, supervising the executor (module docstring)."""

    def __init__(
        self,
        campaign: Campaign,
        ledger: Ledger,
        *,
        executor: ExecutorHandle | Executor,
        slots: int = 1,
        batch_size: int | None = None,
        progress: Progress | None = None,
        batch_fn: Callable[[BatchTask], BatchResult] = execute_batch,
        signals: StopSignals | None = None,
        view: LiveView | None = None,
    ) -> None:
        self.campaign, self.ledger = campaign, ledger
        self.view = view  # the live view (``--live``): told the progress and each committed batch
        self.handle = executor if isinstance(executor, ExecutorHandle) else ExecutorHandle(executor, slots)
        self.slots = self.handle.slots
        self.requested = batch_size
        self.progress = progress
        self.batch_fn = batch_fn
        self.signals = signals
        self.inflight: dict[Future, _Batch] = {}
        self.longest_s = 0.0  # longest submit-to-result time of a batch so far [s]
        self.deadline: float | None = None  # once stopping: when running batches are abandoned
        self.bound_s = 0.0
        self._next_probe = 0.0
        self.failed_in_row = 0  # a real rig's points failed in a row (BatchResult.failure_limit)

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
            directory=str(self.ledger.directory.resolve()),
            campaign=c.name,
            campaign_source=c.source,
            rig=c.rig_ref,
            rig_search=c.rig_search,
            rig_safety=dict(c.rig_safety),
            fs=float(fs),
            duration=float(duration),
            runs=tuple(runs),
            samples_hz=c.logging.get("samples_hz"),
            precision=c.logging.get("precision", "float64"),
            metadata=c.metadata,
            rig_link=c.rig_link,
        )

    def _submit(self, key: str, seqs: Sequence[int], signals: StopSignals, out: Outcome) -> None:
        rows = self.ledger.rows_at(seqs, "id, parameters, batch_key, attempts")  # what a batch needs
        live = self.handle.live
        slot = live.reserve() if live is not None else None
        task = replace(self._task(key, rows), live_at=slot)
        ids = [r.point_id for r in task.runs]
        self.ledger.claim(ids)
        h = self.handle
        try:
            signals.interruptible = h.in_process
            try:
                future = h.executor.submit(self.batch_fn, task)
            finally:
                signals.interruptible = False
        except KeyboardInterrupt:  # a real rig's run, stopped by a second Ctrl-C: its points stay claimed
            raise
        except Exception as exc:  # the executor refused the batch (broken pool, lost cluster): nothing ran
            self._release(slot)
            self.ledger.unclaim(ids)
            refused = f"the executor refused a batch: {type(exc).__name__}: {exc}"
            out.stop_reason = out.stop_reason or (_WORKER_DIED if isinstance(exc, BrokenExecutor) else refused)
            return
        params = [r.parameters for r in task.runs] if self.view else []
        self.inflight[future] = _Batch(
            ids, task.duration, round(task.fs * task.duration), time.monotonic(), slot, params
        )
        if self.progress:
            self.progress.started_runs(len(ids))

    def _release(self, slot: int | None) -> None:
        if self.handle.live is not None:
            self.handle.live.release(slot)

    def live(self, whole: int = 0) -> None:
        """Tell the progress what the live channel says: run-equivalents done (Σ runs × share of the
        batch's ticks done) and runs started, over the batches in flight; ``whole``: runs of a
        returned batch not yet counted (started, all ticks done). Nothing without a channel."""
        live = self.handle.live
        if self.progress is None or live is None:
            return
        done, started = float(whole), whole
        for batch in self.inflight.values():
            ticks = live.ticks(batch.slot)
            if ticks != QUEUED:
                started += len(batch.ids)
                done += len(batch.ids) * min(1.0, ticks / batch.ticks) if batch.ticks else 0.0
        self.progress.live(done, started)

    def _watched(self) -> tuple[str, Any, RunSignals] | None:
        """The live view's run under way: the representative run of the oldest batch that has
        signals in the live channel (point id, grid parameters, signals so far); None: none."""
        live = self.handle.live
        for batch in self.inflight.values() if live is not None else ():  # in the order submitted
            signals = live.signals(batch.slot)
            if signals is not None:
                i = representative(len(batch.ids))
                return batch.ids[i], batch.parameters[i] if batch.parameters else {}, signals
        return None

    def _collect(self, future: Future, out: Outcome) -> None:
        batch = self.inflight.pop(future)
        self._release(batch.slot)  # its worker has returned (or never started it): nothing writes the slot now
        counted = 0
        try:
            if future.cancelled():
                self.ledger.unclaim(batch.ids)
                return
            self.live(whole=len(batch.ids))  # its runs whole until each is counted: the position never jumps back
            self.longest_s = max(self.longest_s, time.monotonic() - batch.submitted)
            exc = future.exception()
            if isinstance(exc, BrokenExecutor):  # a worker process died: every running batch is lost with it
                out.stop_reason = out.stop_reason or _WORKER_DIED
                self._abandon(out)
                return
            if exc is not None:  # the worker itself broke (could not write): stop, points stay claimed
                out.stop_reason = out.stop_reason or f"a worker failed: {type(exc).__name__}: {exc}"
                return
            result: BatchResult = future.result()
            if result.unrun:  # stopped by the runner (Ctrl-C) before it ran to the end: nothing published
                self.ledger.unclaim(batch.ids)
                return
            self.ledger.commit(*result.records)
            if self.view:
                self.view.finished(result.records, dict(zip(batch.ids, batch.parameters)), self.ledger.directory)
            for record in result.records:
                out.committed += 1
                counted += 1
                if self.progress:
                    self.progress.update(record.outcome)
            if result.stop:
                out.stop_reason = out.stop_reason or result.stop
            elif result.failure_limit:
                self._count_failures(result, out)
        finally:
            if self.progress:  # runs that will not be counted in this session (unclaimed, left claimed)
                self.progress.returned(len(batch.ids) - counted)
                self.live()

    def _count_failures(self, result: BatchResult, out: Outcome) -> None:
        """A real rig's points failed in a row: say each, stop at the rig's ``max_consecutive_failures``."""
        for record in result.records:
            self.failed_in_row = self.failed_in_row + 1 if record.outcome == "failed" else 0
        if not self.failed_in_row:
            return
        last = result.records[-1]
        why = (last.outcome_record or {}).get("message", "")
        limit = result.failure_limit
        if self.failed_in_row >= limit:
            out.stop_reason = out.stop_reason or (
                f"{self.failed_in_row} points in a row failed on the rig (the rig file's "
                f"max_consecutive_failures = {limit}); the last, {last.point_id}: {why}"
            )
        else:
            self._say(
                f"point {last.point_id} failed on the rig ({why}); going on: {limit} failures in a row "
                f"stop the campaign, {self.failed_in_row} so far"
            )

    def _abandon(self, out: Outcome) -> None:
        """Give up on every running batch now: their points stay claimed for ``resume``."""
        if self.inflight:
            self.handle.abandon()  # not future.cancel(): a pool then fails on a cancelled future it still held
            for batch in self.inflight.values():
                self._release(batch.slot)
                if self.progress:
                    self.progress.returned(len(batch.ids))
            self.inflight.clear()
            self.live()
            out.abandoned = True

    def _stopping(self, out: Outcome, pending: deque, why: str, *, interrupted: bool = False) -> None:
        """Stop submitting: drop pending batches; queued ones are not started (the workers' stop
        level, and cancelled where that is safe), running ones stop now when ``interrupted`` (on a
        pool or Dask), else finish; all within a deadline."""
        pending.clear()
        running = sum(len(b.ids) for b in self.inflight.values() if self._started(b))
        queued = sum(len(b.ids) for b in self.inflight.values()) - running
        stop = self.handle.stop
        if stop is not None:
            stop(STOP_RUNNING if interrupted else START_NOTHING)
        if self.handle.cancel_queued:  # not a running one: a Dask future cancels, its worker runs on
            for future, batch in list(self.inflight.items()):
                if not self._started(batch) and future.cancel():
                    self._collect(future, out)
        expected = max([self.longest_s, *(b.expected_s for b in self.inflight.values())], default=0.0)
        self.bound_s = math.ceil(2.0 * expected + GRACE_S)  # a batch may wait behind one running on its slot
        self.deadline = time.monotonic() + self.bound_s
        if not self.inflight:
            return
        again = "Ctrl-C again to abandon them now"
        if stop is not None and interrupted:
            self._say(
                f"{why}: stopping the {running} run(s) in flight now (rig left safe, nothing logged); they and "
                f"{queued} queued stay planned for resume ({again})"
            )
        else:
            self._say(
                f"{why}: finishing the {running} run(s) in flight, at most {self.bound_s:.0f} s; {queued} queued "
                f"stay planned ({again})"
            )

    def _started(self, batch: _Batch) -> bool:
        """Whether a worker has taken ``batch`` (without a live channel: assumed so)."""
        live = self.handle.live
        return live is None or live.ticks(batch.slot) != QUEUED

    def _stalled(self, now: float) -> str:
        """Why a started batch counts as dead: its live ticks have not moved for its
        :func:`stall_limit_s` ("" if every batch moves, waits for a worker, or has no channel)."""
        live = self.handle.live
        if live is None:
            return ""
        for batch in self.inflight.values():
            if batch.slot is None:
                continue
            ticks = live.ticks(batch.slot)
            if ticks != batch.seen:
                batch.seen, batch.seen_at = ticks, now
            elif ticks != QUEUED and now - batch.seen_at > stall_limit_s(batch, ticks):
                return (
                    f"a worker made no progress for {now - batch.seen_at:.0f} s (at tick {ticks} of "
                    f"{batch.ticks}; stopped with SIGSTOP, or hung?); the running batches were abandoned"
                )
        return ""

    def _supervise(self, signals: StopSignals, out: Outcome, pending: deque) -> None:
        """Ctrl-C, a failure, a lost or stalled worker or a passed deadline: what the loop does next."""
        now = time.monotonic()
        if now >= self._next_probe:
            self._next_probe = now + PROBE_S
            reason = self.handle.probe()
            if reason:
                out.stop_reason = out.stop_reason or reason
            if self.handle.orphaned() and self.inflight:  # their results can never come back: do not wait
                self._abandon(out)
                return
        stalled = self._stalled(now)
        if stalled:  # as a dead worker: its batch will never return
            out.stop_reason = out.stop_reason or stalled
            self._abandon(out)
            return
        if signals.count >= 2 and self.inflight:
            out.interrupted = True
            self._say("interrupted again: abandoning the running runs now (resume settles them)")
            self._abandon(out)
        elif signals.count and not out.interrupted:
            out.interrupted = True
            self._stopping(out, pending, "interrupted", interrupted=True)
        elif out.stop_reason and self.deadline is None:
            self._stopping(out, pending, "stopping")
        if self.deadline is not None and now > self.deadline and self.inflight:
            self._say(f"the running batches did not finish within {self.bound_s:.0f} s: abandoned")
            self._abandon(out)

    def run(self) -> Outcome:
        """Run every planned point; returns when done, stopped, or interrupted."""
        out = Outcome()
        t0 = time.monotonic()
        self.deadline = None  # a guided campaign runs one session per round
        pending = deque(planned_batches(self.ledger, self.slots, self.requested))
        max_inflight = self.handle.max_inflight
        own = self.signals is None
        signals = self.signals or StopSignals()
        with signals if own else contextlib.nullcontext():
            try:
                while pending or self.inflight:
                    self._supervise(signals, out, pending)
                    if out.abandoned:
                        break
                    while pending and len(self.inflight) < max_inflight and self.deadline is None:
                        self._submit(*pending.popleft(), signals, out)
                        if signals.count or out.stop_reason:
                            break
                    if not self.inflight:
                        continue
                    done, _ = wait(list(self.inflight), timeout=POLL_S, return_when=FIRST_COMPLETED)
                    for future in done:
                        if future in self.inflight:
                            self._collect(future, out)
                    self.live()
                    if self.progress:
                        self.progress.tick()
                        if self.view:
                            self.view.progress(self.progress, self._watched)
            except KeyboardInterrupt:  # only from a real rig's run in this process (StopSignals.interruptible)
                out.interrupted = out.abandoned = True
                self.inflight.clear()
            except LedgerWriteError as exc:  # a full disk: nothing more can be committed; resume accepts the logs
                out.stop_reason = out.stop_reason or str(exc)
                self._abandon(out)
            out.signals = signals.count
        out.elapsed_s = time.monotonic() - t0
        out.counts = self.ledger.by_outcome()
        out.complete = not (out.counts.get("planned", 0) or out.counts.get("claimed", 0))
        return out

    def _say(self, message: str) -> None:
        if self.progress:
            self.progress.write(message)


@dataclass
class _Batch:
    """A submitted batch: its point ids, run duration [s], ticks, submit time (monotonic), its
    slot in the live channel (None: none) and, for the live view, its points' grid parameters."""

    ids: list[str]
    duration: float
    ticks: int
    submitted: float
    slot: int | None = None
    parameters: list[Any] = field(default_factory=list)
    seen: int = QUEUED  # the live ticks last read, and when they last changed (monotonic)
    seen_at: float = 0.0

    @property
    def expected_s(self) -> float:
        """How long it may take [s]: a real rig its duration; a twin the tick cost model of
        :func:`batch_size` with a margin of 10 for rigs heavier than the motor (the plate)."""
        return max(self.duration, 10.0 * self.ticks * (TICK_OVERHEAD_S + len(self.ids) * RUN_TICK_S))
