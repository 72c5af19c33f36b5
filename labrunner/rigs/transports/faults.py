"""Link faults the emulated device injects into what it sends (for tests and ``labrunner emulate``).

:class:`FaultyLink` wraps the device's link: each frame the device sends may be dropped,
delayed, duplicated, followed by garbage (random bytes on a serial line; a malformed frame on
CAN), by a stale repeat of an earlier frame, by a spoofed frame (this node's id on a kind only
the host sends), or by a CAN error frame. ``replay`` sends, before each measurement, the previous
run's frame of that tick and channel (a device replaying a stale buffer: same sequence numbers,
old values and times); ``clock_reset_tick`` restarts the device's timestamps at 0 from that tick
of each run (a device whose clock was reset). ``die_after_s`` after the first run's set-up silences the device
for good (the emulator stops answering, like a board that lost power).
"""

from __future__ import annotations

import heapq
import itertools
import random
import time
from dataclasses import dataclass

import can

from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.can import CanLink
from labrunner.rigs.transports.framing import encode_frame
from labrunner.rigs.transports.link import Link
from labrunner.rigs.transports.protocol import FIXED_PAYLOAD, End, Frame, Kind, can_id
from labrunner.rigs.transports.serial import SerialLink


@dataclass(frozen=True)
class LinkFaults:
    """Per-frame probabilities (0..1) and delays of the faults the device injects."""

    drop: float = 0.0
    delay_ms: float = 0.0  # every frame sent this much later
    garbage: float = 0.0
    duplicate: float = 0.0
    stale: float = 0.0  # repeat a frame sent 10 frames earlier
    spoof: float = 0.0
    error_frame: float = 0.0  # CAN only
    die_after_s: float = float("inf")  # counted from the first run's set-up
    replay: bool = False  # before each measurement, the previous run's frame of the same tick and channel
    clock_reset_tick: int = 0  # from this tick of each run on, the device's clock restarts at 0 (0: never)
    seed: int = 0

    @property
    def any(self) -> bool:
        return (
            any((self.drop, self.delay_ms, self.garbage, self.duplicate, self.stale, self.spoof, self.error_frame))
            or self.die_after_s != float("inf")
            or self.replay
            or self.clock_reset_tick > 0
        )


class FaultyLink:
    """``inner`` (a :class:`~.link.Link`) with :class:`LinkFaults` applied to what it sends;
    delayed frames go out in :meth:`pump`. Everything else is the inner link's."""

    def __init__(self, inner: Link, faults: LinkFaults) -> None:
        self.inner, self.faults = inner, faults
        self.node_id, self.end, self.counters = inner.node_id, inner.end, inner.counters
        self.injected: dict[str, int] = {
            k: 0 for k in ("drop", "garbage", "duplicate", "stale", "spoof", "error_frame", "replay", "clock_reset")
        }
        self._rng = random.Random(faults.seed)
        self._delayed: list[tuple[float, int, Frame]] = []
        self._order = itertools.count()
        self._history: list[Frame] = []
        self._runs: tuple[dict, dict] = ({}, {})  # measurement frames by (seq, channel): previous run's, this run's
        self._last_seq = -1
        self._clock_zero: int | None = None  # the timestamp the reset clock counts from
        self.silent_from = float("inf")  #: monotonic time the device dies (die_after_s after its first run began)

    @property
    def max_payload(self) -> int:
        return self.inner.max_payload

    @property
    def dead(self) -> bool:
        return time.monotonic() >= self.silent_from

    def send(self, frame: Frame) -> None:
        if self.dead:
            return
        if frame.kind == Kind.MEASUREMENT and (self.faults.replay or self.faults.clock_reset_tick):
            frame = self._replay_or_reset(frame)
        f, rng = self.faults, self._rng
        self._history = (self._history + [frame])[-11:]
        if rng.random() < f.drop:
            self.injected["drop"] += 1
            return
        copies = 2 if rng.random() < f.duplicate else 1
        self.injected["duplicate"] += copies - 1
        for _ in range(copies):
            if f.delay_ms:
                heapq.heappush(self._delayed, (time.monotonic() + f.delay_ms * 1e-3, next(self._order), frame))
            else:
                self.inner.send(frame)
        if rng.random() < f.stale and len(self._history) == 11:
            self.injected["stale"] += 1
            self.inner.send(self._history[0])
        for name, inject in (("garbage", self._garbage), ("spoof", self._spoof), ("error_frame", self._error_frame)):
            if rng.random() < getattr(f, name):
                self.injected[name] += 1
                inject()

    def _replay_or_reset(self, frame: Frame) -> Frame:
        """A measurement frame as a device with a reset clock sends it, after the previous run's
        frame of the same tick and channel when replaying."""
        msg = m.unpack(frame)
        previous, current = self._runs
        if msg.seq < self._last_seq and self._last_seq < 2**16 - 2**10:  # a new run (not the u16 wrap)
            self._runs = previous, current = current, {}
            self._clock_zero = None
        self._last_seq = msg.seq
        if isinstance(msg, m.TickEnd) and 0 < self.faults.clock_reset_tick <= msg.seq:
            if self._clock_zero is None:
                self._clock_zero = msg.timestamp_us
                self.injected["clock_reset"] += 1
            frame = m.pack(msg._replace(timestamp_us=msg.timestamp_us - self._clock_zero))
        key = (msg.seq, msg.channel)
        if self.faults.replay and key in previous:
            self.injected["replay"] += 1
            self.inner.send(previous[key])
        current[key] = frame
        return frame

    def pump(self) -> None:
        """Send the delayed frames that are due."""
        now = time.monotonic()
        while self._delayed and self._delayed[0][0] <= now:
            self.inner.send(heapq.heappop(self._delayed)[2])

    def next_due(self) -> float | None:
        return self._delayed[0][0] if self._delayed else None

    def recv(self, timeout: float) -> Frame | None:
        if self.dead:
            time.sleep(timeout)
            return None
        return self.inner.recv(timeout)

    def close(self) -> None:
        self.inner.close()

    # -- injected traffic ------------------------------------------------------------------------
    def _garbage(self) -> None:
        noise = bytes(self._rng.randrange(256) for _ in range(self._rng.randrange(1, 24)))
        if isinstance(self.inner, SerialLink):
            self.inner.port.write(noise)
        elif isinstance(self.inner, CanLink):  # this node's measurement id with a short payload
            self._can_send(can_id(self.node_id, Kind.MEASUREMENT, End.DEVICE), noise[: FIXED_PAYLOAD - 1])

    def _spoof(self) -> None:
        payload = bytes(FIXED_PAYLOAD)
        if isinstance(self.inner, SerialLink):
            self.inner.port.write(encode_frame(self.node_id, int(Kind.INPUT), payload))
        elif isinstance(self.inner, CanLink):
            self._can_send(can_id(self.node_id, Kind.INPUT, End.HOST), payload)

    def _error_frame(self) -> None:
        if isinstance(self.inner, CanLink):
            self.inner.bus.send(can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False, dlc=0))

    def _can_send(self, arbitration_id: int, data: bytes) -> None:
        self.inner.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False))


class LateInputRig:
    """``rig`` applying each input ``ticks`` ticks late (the safe input before then): a device
    whose actuator path lags its law (``labrunner emulate --input-delay N``). The law's u is what
    the device logs and y is measured, so the law check and ``conform`` cannot see it; ``check-rig``'s
    dead-time test can (docs/control-laws.md, "What the checks do not cover")."""

    def __init__(self, rig, ticks: int) -> None:
        self._rig, self.ticks = rig, int(ticks)
        self._queue: list = []

    def __getattr__(self, name: str):
        return getattr(self._rig, name)

    def reset(self, batch, seeds, fs, overrides=None):
        y = self._rig.reset(batch, seeds, fs, overrides)
        self._queue = [self._rig.applied_input.copy() for _ in range(self.ticks)]
        return y

    def step(self, u):
        self._queue.append(u)
        return self._rig.step(self._queue.pop(0))
