"""Bulk transfer over any frame link: sequence-numbered, CRC-32-checked blocks in indexed frames,
with cumulative acknowledgements, selective retransmission requests and a send window (pure:
frames go through callbacks, time is passed in).

Why not ISO-TP (ISO 15765-2): its consecutive frames carry a 4-bit index (16 lost frames go
unseen), it has no checksum of its own, a classic transfer ends at 4095 bytes, and it repeats a
whole transfer after any loss; a plate run's samples are megabytes. Our layer is one level, the
same on classic CAN, CAN FD and serial (docs/device-loop.md, "Bulk transfer"):

* **block** — ``seq`` u32, ``transfer`` u16, ``kind`` u8, ``flags`` u8, ``length`` u16, ``body``,
  CRC-32 (zlib's, over everything before it); the unit that is numbered, checked, acknowledged
  and resent. ``transfer`` names the run both streams belong to (the host draws it), so a late
  copy of an earlier run's block is never taken for this run's;
* **frame** — a link payload of at most ``max_payload`` bytes: frame index u8 (0 starts a
  block) and the next ``max_payload − 1`` bytes of the block; a block spans ≤ 256 frames;
* **ACK** — 8 bytes: ``code`` u8 (bits 0–6: 1 ACK: every block < ``seq`` arrived; 2 NACK:
  resend ``seq``; 3 CANCEL: the receiver gave up; bit 7: the stream acknowledged, 0 host →
  device, 1 device → host), ``window`` u8 (blocks beyond ``seq`` the receiver takes),
  ``transfer`` u16, ``seq`` u32.

A receiver delivers blocks in order; a frame out of index order drops the block it belonged to
(counted), a block failing its CRC is dropped (counted); the receiver asks by NACK for a block
that broke once its header had arrived, and for a gap a later good block reveals. A sender resends what stays unacknowledged for ``retry_s``.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

BLOCK = struct.Struct("<IHBBH")  # seq, transfer, kind, flags, body length
ACK = struct.Struct("<BBHI")  # code | direction << 7, window, transfer, seq
CRC = struct.Struct("<I")
MAX_FRAMES = 256
BLOCK_BYTES = 4096  #: largest block a sender makes (a lost frame costs one block: keep them small)
BLOCK_FRAMES = 64  #: and at most this many frames (one lost frame in 256 breaks 2 in 3 such blocks)
WINDOW_BYTES = 32768  #: unacknowledged bytes a sender keeps in flight (a receiver's buffers hold them)
FLAG_LAST = 0x01  # the last block of a transfer (description) or of a run's results (verdict)

ACK_OK, NACK, CANCEL = 1, 2, 3
TO_DEVICE, TO_HOST = 0, 1  # stream directions (the ``direction`` of an ACK)


def max_body(max_payload: int) -> int:
    """Largest block body a link with ``max_payload``-byte frames carries in ≤ 256 frames."""
    if max_payload < 2:
        raise ValueError(f"bulk frames need a payload of at least 2 bytes, got {max_payload}")
    return min(MAX_FRAMES * (max_payload - 1) - BLOCK.size - CRC.size, 0xFFFF)


@dataclass(frozen=True)
class Block:
    """One bulk block: sequence number, transfer id, kind, flags, body."""

    seq: int
    transfer: int
    kind: int
    flags: int
    body: bytes

    def encode(self) -> bytes:
        head = BLOCK.pack(self.seq % 2**32, self.transfer, self.kind, self.flags, len(self.body)) + self.body
        return head + CRC.pack(zlib.crc32(head))

    def frames(self, max_payload: int) -> list[bytes]:
        """The block cut into link payloads: index byte + up to ``max_payload − 1`` bytes."""
        if len(self.body) > max_body(max_payload):
            raise ValueError(f"block body of {len(self.body)} bytes exceeds {max_body(max_payload)}")
        raw, step = self.encode(), max_payload - 1
        return [bytes((i,)) + raw[at : at + step] for i, at in enumerate(range(0, len(raw), step))]


@dataclass
class Counters:
    """What a receiver saw go wrong, for the run's diagnostics."""

    frames: int = 0
    blocks: int = 0
    crc_errors: int = 0  # blocks dropped for a bad CRC-32
    broken: int = 0  # blocks dropped for a missing or out-of-order frame
    duplicates: int = 0  # blocks that had arrived before (a resend crossed an ACK)
    foreign: int = 0  # blocks of another transfer (a late copy from an earlier run)
    nacks: int = 0  # retransmission requests sent

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class Assembler:
    """Frames → blocks of one stream, in arrival order; drops and counts broken ones."""

    def __init__(self, counters: Counters) -> None:
        self.counters = counters
        self.lost: list[tuple[int, int]] = []  # (transfer, seq) of broken blocks whose header had arrived
        self._buf = bytearray()
        self._next = -1  # the frame index expected next; −1: waiting for a block's first frame
        self._need = 0  # bytes of the block in progress (0 until its header has arrived)

    def feed(self, payload: bytes) -> Block | None:
        self.counters.frames += 1
        if not payload:
            return None
        index = payload[0]
        if index == 0:
            if self._next > 0:
                self._broken()  # the block in progress lost its tail
            self._buf, self._next, self._need = bytearray(), 0, 0
        elif index != self._next:
            if self._next > 0:
                self._broken()
            self._next = -1
            return None
        self._buf += payload[1:]
        self._next = (index + 1) % MAX_FRAMES
        if not self._need and len(self._buf) >= BLOCK.size:
            self._need = BLOCK.size + BLOCK.unpack_from(self._buf)[4] + CRC.size
        if not self._need or len(self._buf) < self._need:
            return None
        raw, self._next = bytes(self._buf[: self._need]), -1  # padding after the CRC is ignored
        if zlib.crc32(raw[: -CRC.size]) != CRC.unpack_from(raw, len(raw) - CRC.size)[0]:
            self.counters.crc_errors += 1
            return None
        seq, transfer, kind, flags, n = BLOCK.unpack_from(raw)
        return Block(seq, transfer, kind, flags, raw[BLOCK.size : BLOCK.size + n])

    def _broken(self) -> None:
        """The block in progress lost a frame: counted, and named when its header had arrived (the
        receiver asks for it at once; an unchecked header at worst asks for a block needlessly)."""
        self.counters.broken += 1
        if self._need:
            seq, transfer = BLOCK.unpack_from(self._buf)[:2]
            self.lost.append((transfer, seq))


class Receiver:
    """One stream's receiving end: delivers blocks of one transfer in sequence order, ACKs them,
    NACKs gaps. ``send_ack(payload)`` sends a BULK_ACK; ``direction`` names the stream in it;
    ``transfer`` the transfer taken. With ``follow``, the first block (seq 0) of another transfer
    for which ``follow(transfer)`` is true starts that transfer afresh (the device side: each run
    is a new transfer; ``follow`` refuses the ones it has run).
    """

    def __init__(
        self,
        send_ack: Callable[[bytes], None],
        direction: int,
        *,
        transfer: int | None = None,
        follow: Callable[[int], bool] | None = None,
        window: int = 64,
        nack_s: float = 0.2,
    ) -> None:
        self.send_ack, self.direction, self.window, self.nack_s = send_ack, direction, window, nack_s
        self.transfer, self.follow = transfer, follow
        self.counters = Counters()
        self._assembler = Assembler(self.counters)
        self.expected = 0
        self._held: dict[int, Block] = {}
        self._nacked: dict[int, float] = {}

    def feed(self, payload: bytes, now: float) -> list[Block]:
        """Take one frame; return the blocks now deliverable in order."""
        block = self._assembler.feed(payload)
        self._nack_broken(now)
        if block is None:
            return []
        self.counters.blocks += 1
        if block.transfer != self.transfer:
            if self.follow is None or block.seq != 0 or not self.follow(block.transfer):
                self.counters.foreign += 1
                return []
            self.transfer, self.expected = block.transfer, 0
            self._held.clear()
            self._nacked.clear()
        if block.seq < self.expected or block.seq in self._held:
            self.counters.duplicates += 1
            self._ack(ACK_OK, self.expected)
            return []
        if block.seq >= self.expected + self.window:
            return []  # beyond the window: the sender will resend it
        self._held[block.seq] = block
        out = []
        while self.expected in self._held:
            out.append(self._held.pop(self.expected))
            self._nacked.pop(self.expected, None)
            self.expected += 1
        if out:
            self._ack(ACK_OK, self.expected)
        self._nack_gaps(now)
        return out

    def poll(self, now: float) -> None:
        """Repeat NACKs of gaps still open after ``nack_s`` (call while waiting)."""
        self._nack_gaps(now)

    def _nack_gaps(self, now: float) -> None:
        if not self._held:
            return
        for seq in range(self.expected, max(self._held)):
            if seq not in self._held:
                self._nack(seq, now)

    def _nack_broken(self, now: float) -> None:
        """Ask at once for a block of this transfer that broke on the way, rather than wait for a
        later block to reveal the gap (none may come: the sender's window can be one block)."""
        lost, self._assembler.lost = self._assembler.lost, []
        for transfer, seq in lost:
            if (
                transfer == self.transfer
                and self.expected <= seq < self.expected + self.window
                and seq not in self._held
            ):
                self._nack(seq, now)

    def _nack(self, seq: int, now: float) -> None:
        if now - self._nacked.get(seq, -1e9) >= self.nack_s:
            self._nacked[seq] = now
            self.counters.nacks += 1
            self._ack(NACK, seq)

    def cancel(self) -> None:
        self._ack(CANCEL, self.expected)

    def _ack(self, code: int, seq: int) -> None:
        if self.transfer is not None:
            self.send_ack(ACK.pack(code | self.direction << 7, min(self.window, 255), self.transfer, seq % 2**32))


@dataclass
class _Pending:
    block: Block
    frames: list[bytes]
    sent_at: float = -1e9  # never sent
    resent_at: float = -1e9  # never resent


@dataclass
class Sender:
    """One stream's sending end: numbers blocks, sends within the window, resends what is NACKed
    (a block not again within ``retry_s``/4 of its last resend) and, when nothing is acknowledged
    for ``retry_s``, the oldest unacknowledged block. ``send_frame(payload)`` sends one frame.

    The window is at most ``window`` blocks (by default :data:`WINDOW_BYTES` worth) and what the
    receiver advertises; like TCP's congestion window it halves on a loss (once per window in
    flight, however many of its blocks are NACKed), drops to one block on a timeout and grows by
    one block per acknowledged block, so a link that loses frames because
    it is flooded (a receiver's socket buffer, a busy bus) is not flooded harder by the resends.
    """

    send_frame: Callable[[bytes], None]
    max_payload: int
    direction: int
    transfer: int = 0
    window: int = 0
    retry_s: float = 0.5
    next_seq: int = 0
    acked: int = 0  # every block below this one has arrived
    cancelled: bool = False
    resent: int = 0
    bytes_sent: int = 0
    _pending: dict[int, _Pending] = field(default_factory=dict)
    _nacked: list[int] = field(default_factory=list)
    _advertised: int = 1 << 16
    _cwnd: float = 0.0
    _progress_at: float | None = None  # when the oldest pending block was last acknowledged or resent
    _sent_upto: int = 0  # blocks below this one have been sent at least once
    _recovered: int = 0  # NACKs of blocks below this one belong to a loss event already answered

    def __post_init__(self) -> None:
        if self.window <= 0:
            self.window = max(2, WINDOW_BYTES // (self.body_limit + BLOCK.size + CRC.size))
        self._cwnd = float(self.window)

    @property
    def body_limit(self) -> int:
        """Largest body :meth:`queue` takes."""
        per_frame = self.max_payload - 1
        return min(BLOCK_FRAMES * per_frame, BLOCK_BYTES) - BLOCK.size - CRC.size

    @property
    def done(self) -> bool:
        """Every queued block acknowledged."""
        return self.acked >= self.next_seq

    def queue(self, kind: int, body: bytes, flags: int = 0) -> int:
        """Queue one block; return its sequence number (sent by :meth:`pump`)."""
        block = Block(self.next_seq, self.transfer, kind, flags, bytes(body))
        self._pending[block.seq] = _Pending(block, block.frames(self.max_payload))
        self.next_seq += 1
        return block.seq

    def on_ack(self, payload: bytes) -> None:
        """Take a BULK_ACK payload (ignored unless it acknowledges this stream)."""
        if len(payload) < ACK.size:
            return
        code, window, transfer, seq = ACK.unpack_from(payload)
        code, direction = code & 0x7F, code >> 7
        if direction != self.direction or transfer != self.transfer:
            return
        if code == CANCEL:
            self.cancelled = True
        elif code == ACK_OK and seq > self.acked:
            new = min(seq, self.next_seq) - self.acked
            for s in range(self.acked, self.acked + new):
                self._pending.pop(s, None)
            self.acked += new
            self._advertised = max(1, window)
            self._cwnd = min(float(self.window), self._cwnd + new)
            self._progress_at = None
        elif code == NACK and seq in self._pending and seq not in self._nacked:
            self._nacked.append(seq)
            if seq >= self._recovered:  # one loss event per window in flight (TCP NewReno's recovery point)
                self._cwnd = max(1.0, self._cwnd / 2)
                self._recovered = self._sent_upto

    def finish(self) -> None:
        """Stop sending: the peer has shown it has every block (it answered the last one)."""
        self._pending.clear()
        self._nacked.clear()
        self.acked = self.next_seq

    def pump(self, now: float, budget: int = 1 << 30) -> int:
        """Send NACKed blocks, then new or overdue ones within the window; at most ``budget``
        blocks. Returns how many blocks went out."""
        sent = 0
        while self._nacked and sent < budget:
            p = self._pending.get(self._nacked.pop(0))
            if p is not None and now - p.resent_at >= self.retry_s / 4:
                p.resent_at = now
                self._send(p, now)
                self.resent += 1
                sent += 1
        oldest = self._pending.get(self.acked)
        if oldest is not None and oldest.sent_at > -1e9:
            if self._progress_at is None:
                self._progress_at = now
            elif now - self._progress_at >= self.retry_s and sent < budget:  # a timeout: the oldest again, slowly
                self._send(oldest, now)
                self.resent += 1
                sent += 1
                self._progress_at, self._cwnd = now, 1.0
        for seq in range(self.acked, min(self.next_seq, self.acked + min(int(self._cwnd), self._advertised))):
            if sent >= budget:
                break
            p = self._pending.get(seq)
            if p is not None and p.sent_at == -1e9:
                self._send(p, now)
                sent += 1
        return sent

    def _send(self, p: _Pending, now: float) -> None:
        for frame in p.frames:
            self.send_frame(frame)
            self.bytes_sent += len(frame)
        p.sent_at = now
        self._sent_upto = max(self._sent_upto, p.block.seq + 1)
