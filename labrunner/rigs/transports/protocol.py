"""The labrunner rig protocol v1: message kinds, the CAN identifier plan, raw frames.

A :class:`Frame` is a message kind and its raw payload bytes; :mod:`.messages` packs and unpacks
the fixed 8-byte payloads of the control messages, and the bulk kinds (``BULK_TO_DEVICE``,
``BULK_TO_HOST``, ``BULK_ACK``) carry payloads laid out by the device-loop transfer
(``docs/device-loop.md``) of up to the link's ``max_payload`` bytes. ``docs/protocol.md`` is the
firmware author's reference: byte layouts, timing, the id plan and the serial framing.

CAN identifier plan (11 bits): ``function_code << 7 | node_id``. Lower identifiers win
arbitration, so the function codes are ordered by urgency (SAFE, STOP, ERROR first) and a safety
message of any node beats the data of every node. Node ids are 1..127: 0 is CANopen's NMT
broadcast id, and function codes stop at 13 so no identifier reaches the 0x7F0–0x7FF range that
CAN 2.0A forbids. Every kind has one sender, except BULK_ACK, which either end sends, each on
its own function code (two nodes never send the same identifier with different data).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

PROTOCOL_VERSION = 1


class Kind(IntEnum):
    """Message kinds; the value is the CAN function code (the host's, for BULK_ACK)."""

    SAFE = 0  # host→dev: safe input now, latched until the next SETUP
    STOP = 1  # host→dev: end the run normally: safe input, device idle
    ERROR = 2  # dev→host: an error code; the device went safe
    INPUT = 3  # host→dev: one input channel of one tick (host loop)
    MEASUREMENT = 4  # dev→host: one output channel of one tick, then the tick's trailer
    HEARTBEAT = 5  # host→dev: keep-alive while the host has nothing else to send
    STATUS = 6  # dev→host: the device's heartbeat: state and error counters
    SETUP = 7  # host→dev: host-loop run set-up records (f_s, watchdog, seed)
    HELLO = 8  # host→dev: handshake request
    IDENTITY = 9  # dev→host: handshake answer records
    BULK_TO_DEVICE = 10  # host→dev: bulk transfer segment (run description, ...)
    BULK_TO_HOST = 11  # dev→host: bulk transfer segment (sample blocks, verdict, ...)
    BULK_ACK = 12  # either end: bulk flow control / acknowledgements


class End(IntEnum):
    """The two ends of a link."""

    HOST = 0
    DEVICE = 1

    @property
    def peer(self) -> End:
        return End.DEVICE if self is End.HOST else End.HOST


BULK_ACK_FROM_DEVICE = 13  # function code of BULK_ACK sent by the device
BULK_KINDS = frozenset({Kind.BULK_TO_DEVICE, Kind.BULK_TO_HOST, Kind.BULK_ACK})
FIXED_PAYLOAD = 8  # bytes of every non-bulk payload (one classic CAN frame)

_DEVICE_SENDS = frozenset({Kind.ERROR, Kind.MEASUREMENT, Kind.STATUS, Kind.IDENTITY, Kind.BULK_TO_HOST})


def senders(kind: Kind) -> frozenset[End]:
    """The ends that may send ``kind``."""
    if kind == Kind.BULK_ACK:
        return frozenset(End)
    return frozenset({End.DEVICE if kind in _DEVICE_SENDS else End.HOST})


def function_code(kind: Kind, sender: End) -> int:
    """The 4-bit function code of ``kind`` sent by ``sender`` (raises ValueError if it may not)."""
    if sender not in senders(kind):
        raise ValueError(f"the {sender.name.lower()} does not send {kind.name}")
    return BULK_ACK_FROM_DEVICE if kind == Kind.BULK_ACK and sender == End.DEVICE else int(kind)


def split_function_code(code: int) -> tuple[Kind, End]:
    """(kind, sender) of a function code; raises ValueError for an unassigned code."""
    if code == BULK_ACK_FROM_DEVICE:
        return Kind.BULK_ACK, End.DEVICE
    kind = Kind(code)
    return kind, End.HOST if kind == Kind.BULK_ACK else next(iter(senders(kind)))


NODE_MIN, NODE_MAX = 1, 127


def can_id(node_id: int, kind: Kind, sender: End) -> int:
    """11-bit identifier ``function_code << 7 | node_id`` (0x001..0x6FF: never 0, nothing from 0x700 on)."""
    if not NODE_MIN <= node_id <= NODE_MAX:
        raise ValueError(f"node id must be in [{NODE_MIN}, {NODE_MAX}], got {node_id}")
    return function_code(kind, sender) << 7 | node_id


def split_can_id(arbitration_id: int) -> tuple[int, Kind, End]:
    """(node id, kind, sender) of an identifier made by :func:`can_id`; ValueError if unassigned."""
    return arbitration_id & 0x7F, *split_function_code(arbitration_id >> 7)


@dataclass(frozen=True, slots=True)
class Frame:
    """One message on a link: its kind and raw payload (8 bytes for non-bulk kinds)."""

    kind: Kind
    payload: bytes
