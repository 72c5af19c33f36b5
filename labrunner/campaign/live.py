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

The pool's array also carries one word the other way, the runner's *stop level*
(:meth:`LiveTicks.stop`), read by the worker at each report: :data:`START_NOTHING` — a batch
that a worker takes from now on returns unrun (:class:`Stopped`) instead of starting;
:data:`STOP_RUNNING` — running batches stop too, at their next report (≤ 1 % of their ticks),
the rig put in its safe state by the engine, nothing published. This is how one Ctrl-C stops a
campaign within a second, rather than after every batch already handed to the pool has run (a
queued future of a process pool cannot be cancelled safely: killing the pool later makes its
manager thread fail on it with ``InvalidStateError``). Dask workers share no memory with the
runner: there the level is not seen and running batches finish.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from labrunner.errors import LabrunnerError

QUEUED = -1  # a slot's value while its batch waits for a worker
START_NOTHING = 1  # stop level: batches not yet taken by a worker return unrun
STOP_RUNNING = 2  # stop level: running batches stop at their next report too
_channel: Any = None  # in a pool worker: the shared array (install)


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


class LiveTicks:
    """``slots`` counters of ticks done, one per batch in flight, and the stop level after them
    (module docstring); shared memory when ``context`` (a multiprocessing context) starts the workers."""

    def __init__(self, slots: int, context: Any = None, *, topic: str | None = None) -> None:
        self.array = (context or multiprocessing).RawArray("q", slots + 1)
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

    def stop(self, level: int) -> None:
        """Raise the stop level the pool's workers read (:data:`START_NOTHING`, :data:`STOP_RUNNING`)."""
        self.array[-1] = max(int(self.array[-1]), level)

    def receive(self, event: tuple[float, Any]) -> None:
        """A Dask event ``(time, [slot, serial, ticks])`` from a worker's report (:func:`hook`)."""
        slot, serial, ticks = event[1]
        with self._lock:
            if 0 <= slot < len(self._serials) and self._serials[slot] == serial:
                self.array[slot] = ticks


def install(array: Any) -> None:
    """In a pool worker (its initializer): the runner's shared array."""
    global _channel
    _channel = array


def hook(address: Address | None) -> Callable[[int], None] | None:
    """What the worker hands the engine for the batch at ``address``: passes the ticks done on
    and, in a pool worker, raises :class:`Stopped` when the runner's stop level asks (0 ticks:
    the batch is being taken). None without an address (a real rig) or a channel (a pool worker
    without :func:`install`)."""
    if address is None:
        return None
    if address.topic is not None:
        from distributed import get_worker

        worker, topic, slot, serial = get_worker(), address.topic, address.slot, address.serial

        def send(ticks: int) -> None:
            with contextlib.suppress(Exception):  # best effort: a lost report must never fail the runs
                worker.log_event(topic, [slot, serial, int(ticks)])

        return send
    array = _channel
    if array is None:
        return None

    def write(ticks: int) -> None:
        level = array[len(array) - 1]
        if level >= STOP_RUNNING or (level and ticks == 0):
            raise Stopped("stopped by the runner")
        array[address.slot] = ticks

    return write
