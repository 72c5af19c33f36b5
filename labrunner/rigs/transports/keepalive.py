"""The host's heartbeat during a host-loop run, sent by a thread of its own (``docs/protocol.md`` § Host loop).

During a run the host's INPUT frames feed the device's watchdog, one per tick, so any stall of
the loop's thread (a page fault, a collection, the machine not running it) is silence on the
link. On the 2-core VMs this was measured on, a SCHED_FIFO thread that only sleeps 1 ms is kept
off its CPU for up to 19 ms (hypervisor steal: benchmarks/bench_hostloop.py --stalls) — longer
than a 3-period watchdog at 200 Hz. :class:`Keepalive` sends a HEARTBEAT whenever the host has
sent nothing for a third of the watchdog period, from a thread that waits in the kernel between
frames, so a loop thread held up on one CPU no longer silences the host; the device holds its
last input meanwhile and flags the ticks LATE, as for any late input.

It heartbeats only while the loop makes progress: while the loop has not finished a tick for
``stall_s`` (``max_late_ticks`` periods, the host's own limit on late ticks) it is silent and the
device's watchdog takes over, so a hung host still puts the device safe, ``stall_s`` + one
watchdog period after its last tick. (A loop waiting for a slow device sends its own heartbeats,
:meth:`RemoteRig.keepalive`.)
A dead host process sends nothing at all: the watchdog trips one period after its last frame.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable

from labrunner.errors import RigError
from labrunner.rigs.transports.realtime import realtime

SILENCE_SHARE = 1 / 3  #: a heartbeat goes out after this share of the watchdog period without a host frame


class Keepalive:
    """Heartbeats for one rig: ``send()`` sends one HEARTBEAT (thread-safe, may raise RigError)."""

    def __init__(self, send: Callable[[], None], *, fifo: bool = False) -> None:
        self._send, self._fifo = send, fifo
        self.last_send = self.last_step = time.monotonic()  # set by the loop's thread
        self.sent = 0  # heartbeats this thread sent
        self._silence_s = self._stall_s = 0.0
        self._armed = False
        self._closed = False
        self._wake = threading.Condition()
        self._parked = threading.Event()  # the thread waits for its first arm
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the thread and wait until it is parked (once, before a run's set-up: a new
        thread's first steps hold the interpreter lock, and on a busy machine it can be preempted
        there for longer than a watchdog period)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name="labrunner-keepalive", daemon=True)
            self._thread.start()
            self._parked.wait(1.0)

    def arm(self, watchdog_s: float, stall_s: float) -> None:
        """A run was set up: keep the device's watchdog of ``watchdog_s`` fed while the loop steps."""
        self.start()
        with self._wake:
            self._silence_s, self._stall_s = SILENCE_SHARE * watchdog_s, stall_s
            self.last_step = time.monotonic()
            self._armed = True
            self._wake.notify()

    def disarm(self) -> None:
        """The run ended (SAFE, STOP, a failure): no more heartbeats until the next :meth:`arm`."""
        self._armed = False

    def close(self) -> None:
        with self._wake:
            self._closed, self._armed = True, False
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout=1.0)

    def _serve(self) -> None:
        with realtime(freeze=False) if self._fifo else contextlib.nullcontext():
            while True:
                with self._wake:
                    if self._closed:
                        return
                    now = time.monotonic()
                    if not self._armed:
                        self._parked.set()
                        self._wake.wait()
                        continue
                    if now - self.last_step > self._stall_s:  # the loop is stuck: let the watchdog judge
                        self._wake.wait(self._silence_s)
                        continue
                    due = self.last_send + self._silence_s
                    if now < due:
                        self._wake.wait(due - now)
                        continue
                try:
                    self._send()
                except RigError:
                    self._armed = False  # the link is gone: the loop's thread reports it
                    continue
                self.sent += 1
