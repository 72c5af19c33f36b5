"""Live progress from inside running batches: how many ticks each in-flight batch has done.

A lockstep batch's runs all end together, so counting committed runs alone leaves a slow twin's
campaign at ``0/N, ETA ?`` for its whole first batch. The engine reports the ticks it has done
(:func:`labrunner.engine.run_batch`'s ``progress`` hook, at most ``PROGRESS_CALLS`` times a
batch) and the worker passes them on to the runner, which reads them without blocking:

- **Process pool**: into one slot of a shared-memory array (one aligned 64-bit integer per slot:
  no lock, no torn read). The array is made before the pool starts and reaches each worker
  through the pool's initializer (:func:`install`), which works for the ``fork`` start method in
  use and for ``spawn`` alike.
- **Dask**: its workers share no memory with the runner, so a report is a Dask event
  (``Worker.log_event`` on a topic of this session, sent asynchronously through the scheduler);
  the runner's client subscribes to the topic and writes what arrives into the same kind of
  array (:meth:`LiveTicks.receive`). Events may arrive after their batch's result: each carries
  the slot's serial, and a report for a slot's previous batch is dropped.

Slots are the runner's: the scheduler reserves one for a batch when it submits it and frees it
when the batch's result (or its abandonment) is in; a slot holds :data:`QUEUED` until a worker
takes the batch, then the ticks done. A real rig runs in the runner's own process, one run per
batch, and is counted per run (no channel).

For the live view (``--live``), a pool's slot also holds the signals so far of its batch's
*representative run* (:func:`representative`: its middle point; batches are strided over the
grid, so that point lies mid-grid, where the first would always be the grid's first corner)
(:class:`RunSignals`): its tracked output, reference, error and first input, at most
:data:`SIGNAL_SAMPLES` samples each (a longer run every n-th sample), written by the engine's
``watch`` hook as the batch runs. A slot's samples count is written after its samples, and read
before them, so that the runner never reads a sample not yet written (on a machine that keeps
stores in order, as x86 does; elsewhere a frame may show a stale sample). Dask workers send no
signals (the view shows each run's from its log once its batch is in).

The pool's array also carries one word the other way, the runner's *stop level*
(:meth:`LiveTicks.stop`), read by the worker at each report: :data:`START_NOTHING` — a batch
that a worker takes from now on returns unrun (:class:`Stopped`) instead of starting;
:data:`STOP_RUNNING` — running batches stop too, at their next report (≤ 1 % of their ticks),
the rig put in its safe state by the engine, nothing published. This is how one Ctrl-C stops a
campaign within a second, rather than after every batch already handed to the pool has run (a
queued future of a process pool cannot be cancelled safely: killing the pool later makes its
manager thread fail on it with ``InvalidStateError``). Dask workers share no memory with the
runner: there the runner sends the level to every worker of the cluster (``Client.run`` of
:func:`raise_level`, one round trip through the scheduler), which keeps it per session topic in
a dict of its process that the reports read as cheaply as the pool's word; queued Dask batches
are cancelled besides (safe there). A worker that joins after the stop has not seen it: a batch
it runs finishes, as does one on a worker the message did not reach, within the runner's bound.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from labrunner.errors import LabrunnerError

QUEUED = -1  # a slot's value while its batch waits for a worker
START_NOTHING = 1  # stop level: batches not yet taken by a worker return unrun
STOP_RUNNING = 2  # stop level: running batches stop at their next report too
ROLES = ("output", "reference", "error", "input")  # the signals of a slot's run, in this order
SIGNAL_SAMPLES = 2000  # samples per signal a slot holds; a longer run is kept every n-th sample
_NAMES_BYTES = 1024  # a slot's JSON of the signals' names, units and sampling rate
_channel: Any = None  # in a pool worker: the shared arrays (install)
_levels: dict[str, int] = {}  # in a Dask worker's process: the stop level of each session's topic


class Stopped(LabrunnerError):
    """Raised by a report (:func:`hook`) when the runner's stop level says this batch must end
    now; the worker returns the batch unrun (its points go back to planned)."""


@dataclass(frozen=True)
class Address:
    """Where a batch reports: its slot, the slot's serial (which batch of the slot), and the Dask
    event topic (None: the pool's shared array)."""

    slot: int
    serial: int
    topic: str | None = None


@dataclass(frozen=True)
class RunSignals:
    """A slot's run so far: its signals' names, units and rate, every ``step``-th sample of each role."""

    names: dict[str, str]  # role (ROLES) → the run's signal name
    units: dict[str, str]  # signal name → unit
    fs: float  # the run's sampling rate [Hz]
    step: int  # samples kept: every step-th
    values: np.ndarray  # (len(ROLES), samples kept so far)


class LiveTicks:
    """``slots`` counters of ticks done, one per batch in flight, and the stop level after them
    (module docstring); shared memory when ``context`` (a multiprocessing context) starts the
    workers, with each slot's run signals (``signals``: only for a pool, whose workers can share them)."""

    def __init__(self, slots: int, context: Any = None, *, topic: str | None = None, signals: bool = False) -> None:
        ctx = context or multiprocessing
        self.array = ctx.RawArray("q", slots + 1)
        # per slot: serial of the batch writing, samples written, step; values; names (JSON)
        self.shared: tuple[Any, ...] = (self.array,)
        if signals:
            self.shared += (
                ctx.RawArray("q", 3 * slots),
                ctx.RawArray("d", slots * len(ROLES) * SIGNAL_SAMPLES),
                ctx.RawArray("c", slots * _NAMES_BYTES),
            )
        self.topic = topic
        self._serials = [0] * slots
        self._free = list(range(slots - 1, -1, -1))
        self._lock = threading.Lock()  # receive() runs in the Dask client's thread

    def reserve(self) -> Address | None:
        """A free slot, marked queued; None if every slot is taken (that batch then shows no progress)."""
        with self._lock:
            if not self._free:
                return None
            slot = self._free.pop()
            self._serials[slot] += 1
            self.array[slot] = QUEUED
            return Address(slot, self._serials[slot], self.topic)

    def release(self, address: Address | None) -> None:
        if address is not None:
            with self._lock:
                self._free.append(address.slot)

    def ticks(self, address: Address | None) -> int:
        """Ticks done by the batch at ``address`` (QUEUED before a worker took it and without an address)."""
        return QUEUED if address is None else int(self.array[address.slot])

    def signals(self, address: Address | None) -> RunSignals | None:
        """The run signals of the batch at ``address`` so far (None: none yet, or no such channel)."""
        if address is None or len(self.shared) == 1:
            return None
        header, values, names = self.shared[1:]
        base = 3 * address.slot
        if header[base] != address.serial:  # not taken yet: the slot's previous batch wrote it
            return None
        n = int(header[base + 1])  # before the samples: those it counts are written
        if n <= 0:
            return None
        about = json.loads(names[_NAMES_BYTES * address.slot : _NAMES_BYTES * (address.slot + 1)].rstrip(b"\0"))
        rows = np.frombuffer(values, dtype=np.float64).reshape(-1, len(ROLES), SIGNAL_SAMPLES)[address.slot]
        return RunSignals(about["names"], about["units"], about["fs"], int(header[base + 2]), rows[:, :n].copy())

    def stop(self, level: int) -> None:
        """Raise the stop level the pool's workers read (:data:`START_NOTHING`, :data:`STOP_RUNNING`)."""
        self.array[-1] = max(int(self.array[-1]), level)

    def receive(self, event: tuple[float, Any]) -> None:
        """A Dask event ``(time, [slot, serial, ticks])`` from a worker's report (:func:`hook`)."""
        slot, serial, ticks = event[1]
        with self._lock:
            if 0 <= slot < len(self._serials) and self._serials[slot] == serial:
                self.array[slot] = ticks


def representative(runs: int) -> int:
    """The index of a batch's representative run (module docstring): its middle one."""
    return runs // 2


def install(*shared: Any) -> None:
    """In a pool worker (its initializer): the runner's shared arrays (:attr:`LiveTicks.shared`)."""
    global _channel
    _channel = shared or None


def raise_level(topic: str, level: int) -> None:
    """Run on every Dask worker by the runner (``Client.run``): raise the stop level of the session
    whose reports go to ``topic`` (as :meth:`LiveTicks.stop` does for a pool)."""
    _levels[topic] = max(_levels.get(topic, 0), level)


def _check(level: int, ticks: int) -> None:
    """Raise :class:`Stopped` when the stop ``level`` ends a batch at this report (0 ticks: being taken)."""
    if level >= STOP_RUNNING or (level and ticks == 0):
        raise Stopped("stopped by the runner")


def hook(address: Address | None) -> Callable[[int], None] | None:
    """What the worker hands the engine for the batch at ``address``: passes the ticks done on
    and raises :class:`Stopped` when the runner's stop level asks (the pool's shared word, a Dask
    worker's :func:`raise_level`). None without an address (a real rig) or a channel (a pool worker
    without :func:`install`)."""
    if address is None:
        return None
    if address.topic is not None:
        from distributed import get_worker

        worker, topic, slot, serial = get_worker(), address.topic, address.slot, address.serial

        def send(ticks: int) -> None:
            _check(_levels.get(topic, 0), ticks)
            with contextlib.suppress(Exception):  # best effort: a lost report must never fail the runs
                worker.log_event(topic, [slot, serial, int(ticks)])

        return send
    if _channel is None or _channel[0] is None:
        return None
    array = _channel[0]

    def write(ticks: int) -> None:
        _check(array[len(array) - 1], ticks)
        array[address.slot] = ticks

    return write


def watcher(address: Address | None, ticks: int, fs: float) -> Callable[[int, Mapping[str, Any], Mapping], None] | None:
    """The engine's ``watch`` hook for the batch at ``address`` (``ticks`` per run at ``fs``):
    writes its representative run's role signals into the slot (module docstring). None without a pool's
    signal channel."""
    if address is None or address.topic is not None or _channel is None or len(_channel) < 4:
        return None
    header, values, names = _channel[1:]
    slot, base = address.slot, 3 * address.slot
    step = max(1, -(-ticks // SIGNAL_SAMPLES))
    rows = np.frombuffer(values, dtype=np.float64).reshape(-1, len(ROLES), SIGNAL_SAMPLES)[slot]
    header[base + 1], header[base + 2], header[base] = 0, step, address.serial
    roles: list[str] = []

    def watch(lo: int, block: Mapping[str, Any], channels: Mapping) -> None:
        with contextlib.suppress(Exception):  # best effort: the view must never fail the runs
            write(lo, block, channels)

    def write(lo: int, block: Mapping[str, Any], channels: Mapping) -> None:
        if not roles:  # the first call: which signals, named where the runner reads them
            tracked = str(channels["references"][0])[len("ref_") :]  # type: ignore[index]
            roles.extend([tracked, f"ref_{tracked}", f"e_{tracked}", str(channels["inputs"][0])])  # type: ignore[index]
            units = {n: channels["units"].get(n, "") for n in roles}  # type: ignore[union-attr]
            text = json.dumps({"names": dict(zip(ROLES, roles)), "units": units, "fs": fs}).encode()
            names[_NAMES_BYTES * slot : _NAMES_BYTES * (slot + 1)] = text.ljust(
                _NAMES_BYTES, b"\0"
            )  # ValueError: too long
        first = -(-lo // step) * step  # the first kept sample of this block
        hi = lo + len(block[roles[0]])
        if first >= hi:
            return
        for j, name in enumerate(roles):
            kept = np.asarray(block[name])[first - lo :: step]
            rows[j, first // step : first // step + len(kept)] = kept
        header[base + 1] = -(-hi // step)  # after the samples it counts

    return watch
