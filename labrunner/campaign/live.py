"""Live progress from inside running batches: how many ticks each in-flight batch has done.

A lockstep batch's runs all end together, so counting committed runs alone leaves a slow twin's
campaign at ``0/N, ETA ?`` for its whole first batch. The engine reports the ticks it has done
(:func:`labrunner.engine.run_batch`'s ``progress`` hook, at most ``PROGRESS_CALLS`` times a
batch); the worker writes them into one slot of a shared-memory array that the parent reads
without a lock or a message (a torn read is impossible: one aligned 64-bit integer per slot).

- Slots are the parent's: the scheduler reserves one for a batch when it submits it and frees it
  when the batch's result (or its abandonment) is in; a slot holds :data:`QUEUED` until a worker
  takes the batch, then the ticks done. A freed slot's worker has returned, so nothing writes it.
- The array is made before the pool starts and reaches each worker through the pool's
  initializer (:func:`install`), which works for the ``fork`` start method in use and for
  ``spawn`` alike (a shared ctypes array is inherited, not pickled with each task).
- A Dask cluster's workers share no memory with the parent: no live channel there; the progress
  line says so and counts a batch's runs when the batch returns. A real rig runs in the parent's
  process one run per batch; its count moves per run.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from typing import Any

QUEUED = -1  # a slot's value while its batch waits for a worker
_channel: Any = None  # in a pool worker: the shared array (install)


class LiveTicks:
    """``slots`` shared 64-bit counters, one per batch in flight (module docstring)."""

    def __init__(self, slots: int, context: Any = None) -> None:
        self.array = (context or multiprocessing).RawArray("q", slots)
        self._free = list(range(slots - 1, -1, -1))

    def reserve(self) -> int | None:
        """A free slot, marked queued; None if every slot is taken (that batch then shows no progress)."""
        if not self._free:
            return None
        slot = self._free.pop()
        self.array[slot] = QUEUED
        return slot

    def release(self, slot: int | None) -> None:
        if slot is not None:
            self._free.append(slot)

    def ticks(self, slot: int | None) -> int:
        """Ticks done by the batch in ``slot`` (QUEUED before a worker took it; 0 without a slot)."""
        return 0 if slot is None else int(self.array[slot])


def install(array: Any) -> None:
    """In a pool worker (its initializer): the parent's shared array."""
    global _channel
    _channel = array


def hook(slot: int | None) -> Callable[[int], None] | None:
    """What the worker hands the engine for the batch in ``slot``: writes the ticks done there.
    None outside a pool worker or without a slot (Dask, a real rig, a test's executor)."""
    array = _channel
    if array is None or slot is None:
        return None

    def report(ticks: int) -> None:
        array[slot] = ticks

    return report
