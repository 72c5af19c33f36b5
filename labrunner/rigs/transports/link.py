"""The Link v1 API: one end of a frame link (CAN bus or serial line) and what it counted.

Contract (stable; later changes are additive):

- ``link.end`` is :attr:`End.HOST` or :attr:`End.DEVICE`, ``link.node_id`` the device's node id
  (1..127); a link sends the kinds its end may send and receives the kinds its peer sends.
- ``link.max_payload`` is the most payload bytes one frame carries: 8 on classic CAN, 64 on CAN
  FD and on the serial line. Non-bulk kinds always carry exactly 8 bytes
  (:mod:`~labrunner.rigs.transports.messages`); bulk kinds (``BULK_TO_DEVICE``, ``BULK_TO_HOST``,
  ``BULK_ACK``) carry 1..``max_payload`` raw bytes whose layout the device-loop transfer defines.
  On CAN FD a payload is padded with zero bytes to the next valid data length (12, 16, 20, 24,
  32, 48, 64), so a bulk layout must carry its own length.
- ``send(frame)`` sends one :class:`Frame`, safe to call from several threads (ValueError for a kind this end does not send or a
  payload of the wrong size; :class:`~labrunner.errors.RigError` for a transport failure).
- ``recv(timeout)`` returns the next frame from the peer for this node, or None after ``timeout``
  seconds; it never returns a malformed, spoofed or foreign frame: those are counted in
  ``link.counters`` (:class:`LinkCounters`) and dropped.
- ``close()`` releases the transport.
"""

from __future__ import annotations

import abc
import collections
import threading
from dataclasses import asdict, dataclass

from labrunner.rigs.transports.protocol import BULK_KINDS, FIXED_PAYLOAD, End, Frame, Kind, senders

_RECENT = 4096  # frames remembered to tell this end's echoes from spoofed frames (a bulk burst is
# up to 64 frames a block times the sender's window, and a loopback echo may lag that far behind)


@dataclass
class LinkCounters:
    """What one end of a link sent, received and dropped (counted since the link opened)."""

    sent: int = 0  # frames sent
    received: int = 0  # frames returned by recv
    foreign: int = 0  # frames for other nodes or in other id formats (ignored, not an error)
    echoes: int = 0  # this end's own recent frames coming back (multicast loopback; not an error)
    spoofed: int = 0  # frames with this node's id of a kind only this end sends, not sent by it
    malformed: int = 0  # unassigned function codes, payloads of the wrong size, bad COBS
    crc_errors: int = 0  # serial frames with a bad CRC
    garbage_bytes: int = 0  # serial bytes dropped while resynchronising
    error_frames: int = 0  # CAN error frames seen on the bus

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class Link(abc.ABC):
    """One end of a frame link, filtered to the frames of its peer for its node (see module doc)."""

    def __init__(self, node_id: int, end: End) -> None:
        self.node_id, self.end = int(node_id), End(end)
        self.counters = LinkCounters()
        self._send_lock = threading.Lock()  # a host's loop and keepalive threads share the link
        self._recent: collections.deque[tuple[Kind, bytes]] = collections.deque()  # send order
        self._recent_count: collections.Counter[tuple[Kind, bytes]] = collections.Counter()  # O(1) membership

    @property
    @abc.abstractmethod
    def max_payload(self) -> int:
        """Most payload bytes of one frame on this link."""

    def send(self, frame: Frame) -> None:
        """Send one frame (ValueError: a kind this end does not send, or a bad payload size)."""
        if self.end not in senders(frame.kind):
            raise ValueError(f"the {self.end.name.lower()} does not send {frame.kind.name}")
        n = len(frame.payload)
        if not (1 <= n <= self.max_payload if frame.kind in BULK_KINDS else n == FIXED_PAYLOAD):
            raise ValueError(f"{frame.kind.name} payload of {n} bytes on a link of max_payload {self.max_payload}")
        payload = self._wire_payload(frame.payload)
        with self._send_lock:
            self._send(frame.kind, payload)
            self.counters.sent += 1
            self._remember((frame.kind, payload))

    def _remember(self, key: tuple[Kind, bytes]) -> None:
        """Keep ``key`` among the last :data:`_RECENT` frames sent (a multiset: deque + counts)."""
        self._recent.append(key)
        self._recent_count[key] += 1
        if len(self._recent) > _RECENT:
            old = self._recent.popleft()
            self._recent_count[old] -= 1
            if not self._recent_count[old]:
                del self._recent_count[old]

    def _wire_payload(self, payload: bytes) -> bytes:
        """The payload as the transport carries it (CAN FD pads it to a valid length)."""
        return payload

    @abc.abstractmethod
    def _send(self, kind: Kind, payload: bytes) -> None:
        """Put one checked frame on the transport (RigError on failure)."""

    @abc.abstractmethod
    def recv(self, timeout: float) -> Frame | None:
        """The next frame from the peer, or None after ``timeout`` [s]."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the transport."""

    # -- shared receive filter -----------------------------------------------------------------
    def _accept(self, node: int, kind: Kind, sender: End, payload: bytes) -> Frame | None:
        """The frame if it is for this end, else None after counting why it was dropped."""
        if node != self.node_id:
            self.counters.foreign += 1
            return None
        if sender != self.end.peer:
            if (kind, payload) in self._recent_count:
                self.counters.echoes += 1
            else:
                self.counters.spoofed += 1
            return None
        if kind in BULK_KINDS:
            ok = 1 <= len(payload) <= self.max_payload
        else:
            ok = len(payload) == FIXED_PAYLOAD
        if not ok:
            self.counters.malformed += 1
            return None
        self.counters.received += 1
        return Frame(kind, payload)
