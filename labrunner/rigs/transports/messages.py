"""The fixed 8-byte control messages of protocol v1: named fields, little-endian struct layouts.

:func:`pack` turns a message into a :class:`~.protocol.Frame`, :func:`unpack` a frame back into
its message (ValueError for a payload of the wrong size or an unknown record). ``docs/protocol.md``
has the byte tables; ``rigs/labrunner.dbc`` describes the same layouts for CAN tools and
``tests/test_protocol_dbc.py`` keeps the two equal.

MEASUREMENT frames of one tick are the output channels 0..n−1 and then a trailer on channel
:data:`TICK_CHANNEL` (:class:`TickEnd`) with the device timestamp and the LATE/OVERRUN flags.
SETUP and IDENTITY are sequences of records ``(index, 4-byte value)``.
"""

from __future__ import annotations

import struct
from enum import IntEnum, IntFlag
from typing import NamedTuple

from labrunner.rigs.transports.protocol import FIXED_PAYLOAD, PROTOCOL_VERSION, Frame, Kind


class ErrorCode(IntEnum):
    NONE = 0
    WATCHDOG = 1  # no host frame within the watchdog period: the device went safe
    BAD_FRAME = 2  # undecodable frame or unknown kind
    NOT_RUNNING = 3  # INPUT before a run was set up
    BAD_CHANNEL = 4  # channel index out of range
    SEQUENCE = 5  # INPUT for a tick other than the current one
    DEVICE_FAULT = 6  # the device's own protection (over-current, driver fault, ...)
    BAD_SETUP = 7  # SETUP incomplete or a value out of the device's range
    VERSION = 8  # HELLO with a protocol version the device does not speak
    UNSUPPORTED = 9  # a capability the device lacks (e.g. the device loop)


class DeviceState(IntEnum):
    IDLE = 0
    RUNNING = 1
    SAFE = 2


class DeviceKind(IntEnum):
    """Device kinds in IDENTITY (the signals and units are those of the rig kind of that name;
    OTHER: a kind registered by another package, known by its channel counts)."""

    OTHER = 0
    DCMOTOR = 1
    VALVE = 2
    PLATE = 3


class Capability(IntFlag):
    HOST_LOOP = 0x01  # serves SETUP/INPUT/MEASUREMENT ticks
    DEVICE_LOOP = 0x02  # runs a run description on board (docs/device-loop.md)
    CAN_FD = 0x04  # accepts CAN FD frames (64-byte bulk payloads)
    FLOAT32 = 0x08  # computes its control laws in float32 (docs/control-laws.md tolerance)


FLAG_COMMIT = 0x01  # INPUT: last channel of this tick: the inputs take effect
FLAG_LATE = 0x01  # TickEnd: the tick's input missed its deadline; the previous input was held
FLAG_OVERRUN = 0x02  # TickEnd: the device itself ran this tick late (its clock slipped)
TICK_CHANNEL = 0xFF


class Input(NamedTuple):
    seq: int  # the tick whose measurement this input answers (u_k after y_k)
    channel: int
    flags: int
    value: float


class Measurement(NamedTuple):
    seq: int  # tick k: y_k sampled at t_k = t_0 + k / f_s on the device clock
    channel: int
    flags: int
    value: float


class TickEnd(NamedTuple):
    seq: int
    channel: int  # TICK_CHANNEL
    flags: int  # FLAG_LATE | FLAG_OVERRUN
    timestamp_us: int  # device time of the sample since the run's t_0 [µs] (wraps at 2^32)


class Heartbeat(NamedTuple):
    counter: int


class Status(NamedTuple):
    state: int  # DeviceState
    last_error: int  # ErrorCode
    rejected: int  # frames the device rejected since the run's SETUP (u16, saturating)
    late: int  # ticks with a late input since SETUP (u16, saturating)
    seq: int  # the device's current tick


class Error(NamedTuple):
    code: int
    seq: int
    detail: float


class Safe(NamedTuple):
    seq: int


class Stop(NamedTuple):
    seq: int


class Hello(NamedTuple):
    version: int


class Record(NamedTuple):
    """One SETUP or IDENTITY record: an index and its 4-byte value (layout by index)."""

    index: int
    value: bytes


_LAYOUTS: dict[Kind, tuple[struct.Struct, type]] = {
    Kind.SAFE: (struct.Struct("<H6x"), Safe),
    Kind.STOP: (struct.Struct("<H6x"), Stop),
    Kind.ERROR: (struct.Struct("<BxHf"), Error),
    Kind.INPUT: (struct.Struct("<HBBf"), Input),
    Kind.MEASUREMENT: (struct.Struct("<HBBf"), Measurement),
    Kind.HEARTBEAT: (struct.Struct("<I4x"), Heartbeat),
    Kind.STATUS: (struct.Struct("<BBHHH"), Status),
    Kind.SETUP: (struct.Struct("<B3x4s"), Record),
    Kind.HELLO: (struct.Struct("<B7x"), Hello),
    Kind.IDENTITY: (struct.Struct("<B3x4s"), Record),
}
_TICK = struct.Struct("<HBBI")
_KIND_OF = {cls: kind for kind, (_, cls) in _LAYOUTS.items() if cls is not Record}
assert all(s.size == FIXED_PAYLOAD for s, _ in _LAYOUTS.values()) and _TICK.size == FIXED_PAYLOAD

Message = Input | Measurement | TickEnd | Heartbeat | Status | Error | Safe | Stop | Hello | Record


def pack(message: Message, kind: Kind | None = None) -> Frame:
    """The frame of ``message`` (``kind`` is needed only for a :class:`Record`: SETUP or IDENTITY)."""
    if isinstance(message, TickEnd):
        return Frame(
            Kind.MEASUREMENT, _TICK.pack(message.seq % 2**16, TICK_CHANNEL, message.flags, message.timestamp_us % 2**32)
        )
    kind = kind if kind is not None else _KIND_OF[type(message)]
    layout, _ = _LAYOUTS[kind]
    if hasattr(message, "seq"):
        message = message._replace(seq=message.seq % 2**16)
    return Frame(kind, layout.pack(*message))


def unpack(frame: Frame) -> Message:
    """The message in ``frame``; ValueError for a bulk kind or a payload of the wrong size."""
    if frame.kind not in _LAYOUTS:
        raise ValueError(f"{frame.kind.name} has no fixed layout")
    if len(frame.payload) != FIXED_PAYLOAD:
        raise ValueError(f"{frame.kind.name} payload of {len(frame.payload)} bytes, expected {FIXED_PAYLOAD}")
    if frame.kind == Kind.MEASUREMENT and frame.payload[2] == TICK_CHANNEL:
        return TickEnd(*_TICK.unpack(frame.payload))
    layout, cls = _LAYOUTS[frame.kind]
    return cls(*layout.unpack(frame.payload))


# -- SETUP records: index 0 f_s [Hz] f32, 1 watchdog period [s] f32, 2 seed u32 (starts the run) --
SETUP_FS, SETUP_WATCHDOG, SETUP_SEED = 0, 1, 2
_F32, _U32 = struct.Struct("<f"), struct.Struct("<I")


def setup_frames(fs: float, watchdog_s: float, seed: int) -> list[Frame]:
    """The SETUP records of a host-loop run, in the order they are sent (the seed starts it)."""
    return [
        pack(Record(SETUP_FS, _F32.pack(fs)), Kind.SETUP),
        pack(Record(SETUP_WATCHDOG, _F32.pack(watchdog_s)), Kind.SETUP),
        pack(Record(SETUP_SEED, _U32.pack(seed % 2**32)), Kind.SETUP),
    ]


def setup_value(record: Record) -> float | int:
    """The value of a SETUP record (ValueError for an unknown index)."""
    if record.index in (SETUP_FS, SETUP_WATCHDOG):
        return _F32.unpack(record.value)[0]
    if record.index == SETUP_SEED:
        return _U32.unpack(record.value)[0]
    raise ValueError(f"unknown SETUP record {record.index}")


# -- IDENTITY records --------------------------------------------------------------------------
class Identity(NamedTuple):
    """What the device says it is in the handshake."""

    version: int
    device_kind: int  # DeviceKind
    n_inputs: int
    n_outputs: int
    capabilities: int  # Capability bits
    max_fs: float  # highest sampling rate the device runs [Hz]
    firmware_id: int  # the firmware's build id (u32, e.g. a VCS hash prefix)


IDENTITY_RECORDS = 4
_ID0 = struct.Struct("<BBBB")


def identity_frames(identity: Identity) -> list[Frame]:
    """The IDENTITY records answering a HELLO: 0 version/kind/n_in/n_out, 1 capabilities,
    2 max f_s (f32), 3 firmware id (u32)."""
    i = identity
    values = [
        _ID0.pack(i.version, i.device_kind, i.n_inputs, i.n_outputs),
        _U32.pack(i.capabilities),
        _F32.pack(i.max_fs),
        _U32.pack(i.firmware_id),
    ]
    return [pack(Record(k, v), Kind.IDENTITY) for k, v in enumerate(values)]


def identity_from(records: dict[int, bytes]) -> Identity:
    """The identity from its four records by index (KeyError if one is missing)."""
    return Identity(
        *_ID0.unpack(records[0]), _U32.unpack(records[1])[0], _F32.unpack(records[2])[0], _U32.unpack(records[3])[0]
    )


def hello() -> Frame:
    return pack(Hello(PROTOCOL_VERSION))
