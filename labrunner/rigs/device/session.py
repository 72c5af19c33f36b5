"""Both ends of one device-loop run over bulk messages (docs/device-loop.md, "A run").

Host: DESCRIPTION blocks → device; device: ACCEPT (or REJECT), PROGRESS every :data:`PROGRESS_S`
while it runs (the loop looks every 32 ticks), SAMPLES (during the run when the description says ``stream``,
else after it), VERDICT with FLAG_LAST. Each side ACKs the other's blocks and NACKs gaps;
every block is resent until acknowledged. The ends talk through two callables, medium-agnostic:
``send(kind, payload)`` and ``recv(timeout) -> (kind, payload) | None`` with ``kind`` one of
:data:`TO_DEVICE`, :data:`TO_HOST`, :data:`ACK` (the link adapter maps them to its messages),
or on the device :data:`STOP` (the host's SAFE or STOP: the run ends now); anything else the
adapter deals with itself and hands over as ``(None, payload)``.
"""

from __future__ import annotations

import contextlib
import secrets
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from labrunner.errors import RigError
from labrunner.rigs.device import blocks
from labrunner.rigs.device.description import DescriptionError
from labrunner.rigs.transports import bulk

TO_DEVICE, TO_HOST, ACK = "to_device", "to_host", "ack"
STOP = "stop"  #: what a device's link adapter hands over for the host's SAFE / STOP message
HEARTBEAT = "heartbeat"  #: the host's keep-alive while it has nothing else to send (payload ignored)
PROGRESS_S = 0.25  #: a device sends PROGRESS this often while its loop runs [s]
DEAD_S = 1.0  #: a device that sends no bulk frame for this long is dead or hung (4 PROGRESS periods) [s]
STALL_S = 10.0  #: a transfer that completes no block either way for this long has failed (a lossy link) [s]
Send = Callable[[str, bytes], None]
Recv = Callable[[float], "tuple[str | None, bytes] | None"]


class RunFailed(RigError):
    """A device-loop run the host gave up on: the reason, the ``rows`` that had arrived (its
    partial log) and their device ``clock``."""

    def __init__(self, message: str, rows: np.ndarray, clock: np.ndarray) -> None:
        super().__init__(message)
        self.rows, self.clock = rows, clock


class HostStop(Exception):
    """The host cancelled the run (raised inside the device's loop; the run ends ``failed``)."""


@dataclass
class Transfer:
    """What a host-side run moved and saw: bytes each way, the receiver's counters, resends, times."""

    bytes_to_device: int = 0
    bytes_to_host: int = 0
    blocks_resent: int = 0
    received: dict[str, int] = field(default_factory=dict)
    accept_s: float = 0.0  # description sent → ACCEPT
    run_s: float = 0.0  # ACCEPT → VERDICT
    progress_rate: float = 0.0  # ticks a second from the first to the last PROGRESS, host clock (0: fewer than 2)

    def as_dict(self) -> dict[str, object]:
        return dict(self.__dict__)


def _slices(data: bytes, size: int) -> list[bytes]:
    return [data[i : i + size] for i in range(0, len(data), size)] or [b""]


def run_on_device(
    send: Send,
    recv: Recv,
    max_payload: int,
    description: bytes,
    n_ticks: int,
    n_columns: int,
    fs: float,
    *,
    dead_s: float = DEAD_S,
    stall_s: float = STALL_S,
    heartbeat_s: float = 0.25,
) -> tuple[blocks.Verdict, np.ndarray, np.ndarray, Transfer]:
    """Host side of one run: send ``description``, collect the samples and the verdict; a
    HEARTBEAT goes out whenever the host sent nothing for ``heartbeat_s`` (the device's watchdog).

    Returns the verdict, the (n_samples, n_columns) float32 rows, the device's time of each row
    [s] (a SAMPLES block's first-tick time, then 1/f_s a tick) and the transfer's figures.
    Raises :class:`RunFailed` (a RigError holding the rows that arrived) when the device refuses
    the description, sends no bulk frame for ``dead_s`` (dead or hung), completes no block either
    way for ``stall_s`` (a link too lossy), sends samples that do not fit the run, or the link fails.
    """
    run = _HostRun(send, recv, max_payload, n_ticks, n_columns, fs, heartbeat_s)
    parts = _slices(description, run.tx.body_limit)
    for i, part in enumerate(parts):
        run.tx.queue(blocks.DESCRIPTION, part, bulk.FLAG_LAST if i == len(parts) - 1 else 0)
    t0 = time.monotonic()
    try:
        verdict = run.collect(dead_s, stall_s)
        if verdict.n_samples != run.covered:
            raise RigError(f"the device logged {verdict.n_samples} ticks but sent {run.covered}")
    except RigError as exc:
        with contextlib.suppress(RigError):
            run.rx.cancel()  # the device stops resending this run's results
        raise RunFailed(str(exc), run.rows[: run.covered], run.clock[: run.covered]) from None
    end = time.monotonic()
    out = run.out
    out.bytes_to_device, out.blocks_resent = run.tx.bytes_sent, run.tx.resent
    out.received = run.rx.counters.as_dict()
    out.accept_s = (run.accepted or end) - t0
    out.run_s = end - (run.accepted or t0)
    out.progress_rate = run.progress_rate()
    return verdict, run.rows[: run.covered], run.clock[: run.covered], out


class _HostRun:
    """The host's end of one run: its two bulk streams, the rows that arrived, the timers."""

    def __init__(
        self, send: Send, recv: Recv, max_payload: int, n_ticks: int, n_columns: int, fs: float, heartbeat_s: float
    ):
        self.send, self.recv, self.heartbeat_s = send, recv, heartbeat_s
        self.last_tx = time.monotonic()
        transfer = secrets.randbelow(2**16)  # this run's; the device answers under it
        self.tx = bulk.Sender(lambda p: self._sent(TO_DEVICE, p), max_payload, bulk.TO_DEVICE, transfer)
        self.rx = bulk.Receiver(lambda p: self._sent(ACK, p), bulk.TO_HOST, transfer=transfer)
        self.rows = np.full((n_ticks, n_columns), np.nan, np.float32)
        self.clock = np.full(n_ticks, np.nan)  # the device's time of each row [s]
        self.fs = fs
        self.covered = 0  # rows up to here arrived (SAMPLES blocks come in tick order)
        self.accepted: float | None = None  # when ACCEPT arrived (monotonic)
        self.progress: list[tuple[float, int]] = []  # (arrival, ticks done) of the first and the last PROGRESS
        self.out = Transfer()

    def _sent(self, kind: str, payload: bytes) -> None:
        self.send(kind, payload)
        self.last_tx = time.monotonic()

    def _phase(self) -> str:
        if self.accepted is None:
            return "description"
        return f"run ({self.covered} of {len(self.rows)} ticks received)"

    def progress_rate(self) -> float:
        """The device loop's ticks a second as its PROGRESS blocks arrived (0 from fewer than two): its
        real rate, unlike ticks over ACCEPT → VERDICT, which includes the upload of the results."""
        if len(self.progress) < 2 or self.progress[-1][0] <= self.progress[0][0]:
            return 0.0
        (t0, k0), (t1, k1) = self.progress[0], self.progress[-1]
        return (k1 - k0) / (t1 - t0)

    def collect(self, dead_s: float, stall_s: float) -> blocks.Verdict:
        """Exchange blocks until the VERDICT arrives (RigError on a fault)."""
        heard = progressed = time.monotonic()  # the device's last bulk frame; the last block either way
        while True:
            now = time.monotonic()
            self.tx.pump(now)
            if now - self.last_tx >= self.heartbeat_s:
                self._sent(HEARTBEAT, b"")
            msg = self.recv(0.01)
            now = time.monotonic()
            if now - heard > dead_s:  # PROGRESS comes every 0.25 s while it runs: its loop is dead or hung
                raise RigError(
                    f"no frame from the device for {dead_s:g} s during the {self._phase()}: the device is dead "
                    "or hung, and the rig may not be in its safe state (only the device's own watchdog puts it there)"
                )
            if now - progressed > stall_s:  # frames come, blocks do not: the link loses too much
                raise RigError(
                    f"no block got through either way for {stall_s:g} s during the {self._phase()}: the link "
                    f"loses too many frames; description blocks acknowledged {self.tx.acked}/{self.tx.next_seq}, "
                    f"blocks received {self.rx.expected} ({self.rx.counters.as_dict()})"
                )
            if msg is None:
                self.rx.poll(now)
                continue
            kind, payload = msg
            if kind not in (ACK, TO_HOST):
                continue
            heard = now
            before = (self.tx.acked, self.rx.expected)
            if kind == ACK:
                self.tx.on_ack(payload)
            else:
                self.out.bytes_to_host += len(payload)
                for block in self.rx.feed(payload, now):
                    verdict = self._take(block, now)
                    if verdict is not None:
                        return verdict
            if (self.tx.acked, self.rx.expected) != before:
                progressed = now

    def _take(self, block: bulk.Block, now: float) -> blocks.Verdict | None:
        """One in-order block from the device; the verdict once it arrives (RigError for a block that does not fit)."""
        n_ticks, n_columns = self.rows.shape
        if block.kind in (blocks.ACCEPT, blocks.REJECT):
            self.tx.finish()  # the description arrived: no more resends of it
        if block.kind == blocks.REJECT:
            raise RigError(f"the device refused the run: {block.body.decode('ascii', 'replace')}")
        if block.kind == blocks.ACCEPT:
            ticks, cols = blocks.ACCEPT_BODY.unpack(block.body)
            if (ticks, cols) != (n_ticks, n_columns):
                raise RigError(
                    f"the device accepted {ticks} ticks × {cols} columns, the host asked for {n_ticks} × {n_columns}"
                )
            self.accepted = now
        elif block.kind == blocks.PROGRESS and len(block.body) == blocks.PROGRESS_BODY.size:  # else no rate
            done, _ = blocks.PROGRESS_BODY.unpack(block.body)
            self.progress[1:] = [(now, done)]
        elif block.kind == blocks.SAMPLES:
            first, chunk, t_us = blocks.decode_samples(block.body)
            if first != self.covered or first + len(chunk) > n_ticks or chunk.shape[1] != n_columns:
                raise RigError(
                    f"link fault: SAMPLES block for ticks {first}..{first + len(chunk) - 1} after {self.covered} "
                    "ticks (old blocks replayed, or blocks lost)"
                )
            if first and t_us * 1e-6 <= self.clock[first - 1]:  # a u64 µs clock never wraps: it went back
                raise RigError(
                    f"link fault: the device clock went from {self.clock[first - 1]:.6f} s to {t_us * 1e-6:.6f} s "
                    f"at tick {first} (a device reset, or old blocks replayed)"
                )
            self.rows[first : first + len(chunk)] = chunk
            self.clock[first : first + len(chunk)] = t_us * 1e-6 + np.arange(len(chunk)) / self.fs
            self.covered += len(chunk)
        elif block.kind == blocks.VERDICT:
            return blocks.Verdict.decode(block.body)
        return None


class DeviceSession:
    """Device side: collects a description, runs it with ``execute`` and sends the results.

    ``execute(data, hook, on_accept) -> DeviceRun`` is :func:`labrunner.rigs.device.executor.execute`
    bound to the device's rig; ``clock()`` the monotonic clock [s]; ``upload_silence_s`` how long
    it keeps unacknowledged results for a silent host before it drops them.
    """

    def __init__(
        self,
        send: Send,
        recv: Recv,
        max_payload: int,
        execute: Callable[..., object],
        *,
        upload_silence_s: float = 10.0,
    ) -> None:
        self.send, self.recv, self.max_payload, self.execute = send, recv, max_payload, execute
        self.upload_silence_s = upload_silence_s
        self.runs = 0
        self.ticks_done = 0  # of the run in progress (STATUS's seq)
        self.stopped = False
        self.last_rx = time.monotonic()  # the host's last message (the watchdog's reference)
        self._done: deque[int] = deque(maxlen=16)  # transfers run lately: a late resend never runs again
        self._parts: list[bytes] = []
        self._next: bytes | None = None  # a description completed while results were still uploading
        self.rx = bulk.Receiver(lambda p: self.send(ACK, p), bulk.TO_DEVICE, follow=self._follow)
        self.tx = self._results(0)

    def _follow(self, transfer: int) -> bool:
        """Whether a description starting under ``transfer`` is a new run (then a half-received
        earlier one is dropped)."""
        if transfer in self._done:
            return False
        self._parts = []
        return True

    def _results(self, transfer: int) -> bulk.Sender:
        return bulk.Sender(lambda p: self.send(TO_HOST, p), self.max_payload, bulk.TO_HOST, transfer)

    def on_message(self, kind: str, payload: bytes) -> None:
        """One bulk message from the host; a complete description runs here and now (the device
        is busy until its results are acknowledged, or until the host sends the next description:
        it does so only once it holds the verdict, so a lost final ACK never blocks the next run)."""
        self.last_rx = time.monotonic()
        if kind == ACK:
            self.tx.on_ack(payload)
            return
        if kind != TO_DEVICE:
            return
        data = self._take_description(payload)
        while data is not None:
            self._done.append(self.rx.transfer)
            self.tx = self._results(self.rx.transfer)  # the results go under the description's transfer
            try:
                self._run(data)
            finally:
                self.runs += 1
            data, self._next = self._next, None

    def _take_description(self, payload: bytes) -> bytes | None:
        """Feed one TO_DEVICE frame; the whole description once its last block is in, else None."""
        for block in self.rx.feed(payload, time.monotonic()):
            if block.kind != blocks.DESCRIPTION:
                continue
            self._parts.append(block.body)
            if block.flags & bulk.FLAG_LAST:
                data, self._parts = b"".join(self._parts), []
                return data
        return None

    def _run(self, data: bytes) -> None:
        state = {
            "streamed": 0,
            "stream": False,
            "fs": 1.0,
            "per_block": 1,
            "last": time.monotonic(),
            "watchdog": float("inf"),
        }

        def on_accept(description) -> None:
            state.update(
                stream=description.stream,
                fs=description.fs,
                watchdog=description.watchdog_s,
                per_block=blocks.samples_per_block(self.tx.body_limit, description.n_columns),
            )
            self.tx.queue(blocks.ACCEPT, blocks.ACCEPT_BODY.pack(description.ticks, description.n_columns))
            self._service()

        def tick(done: int) -> None:
            now = time.monotonic()
            if now - state["last"] >= PROGRESS_S:
                state["last"] = now
                self.tx.queue(blocks.PROGRESS, blocks.PROGRESS_BODY.pack(done, blocks.tick_us(done, state["fs"])))
            self.ticks_done = done
            self._service()
            if self.tx.cancelled or self.stopped:
                raise HostStop("stopped by the host")
            if now - self.last_rx > state["watchdog"]:
                raise HostStop(f"watchdog: no message from the host for {now - self.last_rx:.3g} s")

        def hook(first: int, rows: np.ndarray) -> None:  # also called once after the last tick: never raises
            if state["stream"] and first == state["streamed"]:
                self._queue_samples(first, rows, state)
            self._service()

        self.stopped = False
        try:
            run = self.execute(data, hook=hook, on_accept=on_accept, tick=tick)
        except DescriptionError as exc:
            self.tx.queue(blocks.REJECT, str(exc).encode("ascii", "replace")[: self.tx.body_limit], bulk.FLAG_LAST)
            self._upload()
            return
        start = state["streamed"]
        self._queue_samples(start, run.columns[start:], state)
        self.tx.queue(blocks.VERDICT, run.verdict.encode(), bulk.FLAG_LAST)
        self._upload()

    def _queue_samples(self, first: int, rows: np.ndarray, state: dict) -> None:
        n = state["per_block"]
        for at in range(0, len(rows), n):
            k = first + at
            self.tx.queue(blocks.SAMPLES, blocks.encode_samples(k, rows[at : at + n], blocks.tick_us(k, state["fs"])))
        state["streamed"] = first + len(rows)

    def _service(self, timeout: float = 0.0) -> None:
        """Send what the window allows and take the host's ACKs, without blocking the loop."""
        self.tx.pump(time.monotonic())
        while (msg := self.recv(timeout)) is not None:
            kind, payload = msg
            self.last_rx = time.monotonic()
            if kind == ACK:
                self.tx.on_ack(payload)
            elif kind == STOP:
                self.stopped = True
            elif kind == TO_DEVICE:  # resends of this run's description (re-ACKed), or the next run's
                data = self._take_description(payload)
                if data is not None:
                    self._next = data
            timeout = 0.0

    def _upload(self) -> None:
        """Send every queued block until the host has acknowledged them all (or gave up)."""
        last_progress, acked = time.monotonic(), self.tx.acked
        while not (self.tx.done or self.tx.cancelled or self._next is not None):
            self._service(0.005)
            now = time.monotonic()
            if self.tx.acked != acked:
                last_progress, acked = now, self.tx.acked
            elif now - last_progress > self.upload_silence_s:
                return  # the host is gone; the rig is already in its safe state
