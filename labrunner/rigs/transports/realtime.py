"""Real-time scheduling for the processes on a timing path (the emulated device, a host loop).

A device's firmware ticks on a hardware timer; an emulated device on a shared machine is
preempted by whatever else runs. :func:`realtime` asks Linux for ``SCHED_FIFO`` for the calling
thread (it needs root or CAP_SYS_NICE) and gives the old policy back on exit; where it is not
granted it changes nothing and says so. The loops it serves block in ``select`` between frames,
so a real-time thread never spins (and the kernel's RT throttling caps it at 95 % of a core).
It also freezes the objects that exist (``gc.freeze``): a full collection of a large heap (a
long-lived process's) stalls for tens of milliseconds, longer than a watchdog of a few periods;
later collections then scan only what the loop allocates.
"""

from __future__ import annotations

import contextlib
import gc
import os
from collections.abc import Iterator

DEFAULT_PRIORITY = 10  # of 1..99: above every normal thread, below the kernel's own RT threads


@contextlib.contextmanager
def realtime(priority: int = DEFAULT_PRIORITY, freeze: bool = True) -> Iterator[bool]:
    """SCHED_FIFO at ``priority`` for the calling thread while in the block; yields whether granted.
    ``freeze=False`` leaves the collector alone (a helper thread of a loop that froze it)."""
    if not hasattr(os, "sched_setscheduler"):
        yield False
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        yield False
        return
    if freeze:
        gc.freeze()
    try:
        yield True
    finally:
        if freeze:
            gc.unfreeze()
        os.sched_setscheduler(0, policy, param)
