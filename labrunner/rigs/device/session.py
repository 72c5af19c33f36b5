"""Both ends of one device-loop run over bulk messages (docs/device-loop.md, "A run").

Host: DESCRIPTION blocks → device; device: ACCEPT (or REJECT), PROGRESS while it runs (checked
every 1024 ticks, sent when :data:`PROGRESS_S` has passed since the last), SAMPLES (during the run when the description says ``stream``,
else after it), VERDICT with FLAG_LAST. Each side ACKs the other's blocks and NACKs gaps;
every block is resent until acknowledged. The ends talk through two callables, medium-agnostic:
``send(kind, payload)`` and ``recv(timeout) -> (kind, payload) | None`` with ``kind`` one of
:data:`TO_DEVICE`, :data:`TO_HOST`, :data:`ACK` (the link adapter maps them to its messages),
or on the device :data:`STOP` (the host's SAFE or STOP: the run ends now); anything else the
adapter deals with itself and hands over as ``(None, payload)``.
"""

from __future__ import annotations

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
PROGRESS_S = 0.25  #: shortest interval between PROGRESS blocks [s]
Send = Callable[[str, bytes], None]
Recv = Callable[[float], "tuple[str | None, bytes] | None"]


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
    *,
    silence_s: float = 10.0,
    heartbeat_s: float = 0.25,
) -> tuple[blocks.Verdict, np.ndarray, Transfer]:
    """Host side of one run: send ``description``, collect the samples and the verdict; a
    HEARTBEAT goes out whenever the host sent nothing for ``heartbeat_s`` (the device's watchdog).

    Returns the verdict, the (n_samples, n_columns) float32 rows and the transfer's figures.
    Raises RigError when the device refuses the description, delivers no new block (and
    acknowledges none) for ``silence_s``, or sends samples that do not fit the run.
    """
    last_tx = [time.monotonic()]

    def sent(kind: str, payload: bytes) -> None:
        send(kind, payload)
        last_tx[0] = time.monotonic()

    transfer = secrets.randbelow(2**16)  # this run's; the device answers under it
    tx = bulk.Sender(lambda p: sent(TO_DEVICE, p), max_payload, bulk.TO_DEVICE, transfer)
    rx = bulk.Receiver(lambda p: sent(ACK, p), bulk.TO_HOST, transfer=transfer)
    parts = _slices(description, tx.body_limit)
    for i, part in enumerate(parts):
        tx.queue(blocks.DESCRIPTION, part, bulk.FLAG_LAST if i == len(parts) - 1 else 0)
    rows = np.full((n_ticks, n_columns), np.nan, np.float32)
    covered = 0  # rows up to here arrived (SAMPLES blocks come in tick order)
    out = Transfer()
    t0 = last_rx = time.monotonic()
    t_accept = None
    verdict = None
    while verdict is None:
        now = time.monotonic()
        tx.pump(now)
        if now - last_tx[0] >= heartbeat_s:
            sent(HEARTBEAT, b"")
        msg = recv(0.01)
        now = time.monotonic()
        if now - last_rx > silence_s:  # nothing new arrived: a dead device or a link that delivers nothing
            rx.cancel()
            phase = "description" if t_accept is None else f"results ({covered} of {n_ticks} ticks in)"
            raise RigError(
                f"device-loop run: no new block from the device for {silence_s:g} s during the {phase}; "
                f"host sent {tx.acked}/{tx.next_seq} description blocks acknowledged, received {rx.expected} "
                f"blocks ({rx.counters.as_dict()})"
            )
        if msg is None:
            rx.poll(now)
            continue
        kind, payload = msg
        before = (tx.acked, rx.expected)
        if kind == ACK:
            tx.on_ack(payload)
        elif kind == TO_HOST:
            out.bytes_to_host += len(payload)
            for block in rx.feed(payload, now):
                if block.kind in (blocks.ACCEPT, blocks.REJECT):
                    tx.finish()  # the description arrived: no more resends of it
                if block.kind == blocks.REJECT:
                    raise RigError(f"the device refused the run: {block.body.decode('ascii', 'replace')}")
                if block.kind == blocks.ACCEPT:
                    ticks, cols = blocks.ACCEPT_BODY.unpack(block.body)
                    if (ticks, cols) != (n_ticks, n_columns):
                        rx.cancel()
                        raise RigError(
                            f"the device accepted {ticks} ticks × {cols} columns, the host asked for {n_ticks} × {n_columns}"
                        )
                    t_accept = now
                elif block.kind == blocks.SAMPLES:
                    first, chunk, _ = blocks.decode_samples(block.body)
                    if first != covered or first + len(chunk) > n_ticks or chunk.shape[1] != n_columns:
                        rx.cancel()
                        raise RigError(
                            f"SAMPLES block for ticks {first}..{first + len(chunk) - 1} after {covered} ticks"
                        )
                    rows[first : first + len(chunk)] = chunk
                    covered += len(chunk)
                elif block.kind == blocks.VERDICT:
                    verdict = blocks.Verdict.decode(block.body)
        if (tx.acked, rx.expected) != before:
            last_rx = now
    if verdict.n_samples != covered:
        raise RigError(f"the device logged {verdict.n_samples} ticks but sent {covered}")
    end = time.monotonic()
    out.bytes_to_device, out.blocks_resent = tx.bytes_sent, tx.resent
    out.received = rx.counters.as_dict()
    out.accept_s = (t_accept or end) - t0
    out.run_s = end - (t_accept or t0)
    return verdict, rows[:covered], out


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

        def hook(first: int, rows: np.ndarray) -> None:
            if state["stream"] and first == state["streamed"]:
                self._queue_samples(first, rows, state)
            now = time.monotonic()
            if now - state["last"] >= PROGRESS_S:
                state["last"] = now
                done = first + len(rows)
                self.tx.queue(blocks.PROGRESS, blocks.PROGRESS_BODY.pack(done, blocks.tick_us(done, state["fs"])))
            self._service()
            if self.tx.cancelled or self.stopped:
                raise HostStop("stopped by the host")
            if now - self.last_rx > state["watchdog"]:
                raise HostStop(f"watchdog: no message from the host for {now - self.last_rx:.3g} s")

        self.stopped = False
        try:
            run = self.execute(data, hook=hook, on_accept=on_accept)
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
