"""The labrunner rig protocol: small fixed frames between the host (labrunner) and a rig's firmware.

Every frame is a type and 8 payload bytes, so one frame is one classic CAN frame; over a serial
line it is wrapped with a sync byte, the node id and a CRC-8 (``docs/rigs.md`` has the tables).

Payload, little-endian, ``<HBBf``: ``seq`` (u16), ``channel`` (u8), ``flags`` (u8), ``value`` (f32);
except RESET, ``<If``: ``seed`` (u32, in ``seq``) and ``fs`` [Hz] (in ``value``).

======  ===========  =========  =============================================================
type    name         direction  meaning
======  ===========  =========  =============================================================
1       RESET        host→dev   start a run at ``fs``; the device answers with measurement seq 0
2       INPUT        host→dev   input ``channel`` = ``value`` for sample ``seq``; flag COMMIT on
                                the last channel applies the inputs (zero-order hold)
3       MEASUREMENT  dev→host   output ``channel`` = ``value`` after sample ``seq``; flag LAST on
                                the last channel
4       HEARTBEAT    host→dev   keep-alive; the device answers with STATUS
5       STATUS       dev→host   ``channel`` = device state (0 idle, 1 running, 2 safe), ``flags`` =
                                last error code, ``value`` = device time [s]
6       SAFE         host→dev   go to the safe input now and stay there until the next RESET
7       ERROR        dev→host   ``channel`` = error code (:class:`ErrorCode`), ``value`` = detail
======  ===========  =========  =============================================================

Watchdog: a running device that hears nothing from the host for its watchdog period goes to its
safe state by itself and sends ERROR WATCHDOG. ``value`` is float32: θ keeps 1e-7 relative
precision (6e-5 rad at 1000 rad, far below one encoder count).
"""

from __future__ import annotations

import abc
import struct
from dataclasses import dataclass
from enum import IntEnum


class MsgType(IntEnum):
    RESET = 1
    INPUT = 2
    MEASUREMENT = 3
    HEARTBEAT = 4
    STATUS = 5
    SAFE = 6
    ERROR = 7


class ErrorCode(IntEnum):
    NONE = 0
    WATCHDOG = 1  # no host frame within the watchdog period: the device went safe
    BAD_FRAME = 2  # undecodable frame or unknown type
    NOT_RUNNING = 3  # INPUT before RESET
    BAD_CHANNEL = 4  # channel index out of range
    SEQUENCE = 5  # INPUT for a sample other than the next one
    DEVICE_FAULT = 6  # the device's own protection (over-current, driver fault, ...)


class DeviceState(IntEnum):
    IDLE = 0
    RUNNING = 1
    SAFE = 2


FLAG_COMMIT = 0x01  # INPUT: apply the inputs of this sample
FLAG_LAST = 0x01  # MEASUREMENT: last output channel of this sample

HOST_RECEIVES = frozenset({MsgType.MEASUREMENT, MsgType.STATUS, MsgType.ERROR})
DEVICE_RECEIVES = frozenset({MsgType.RESET, MsgType.INPUT, MsgType.HEARTBEAT, MsgType.SAFE})

_BODY = struct.Struct("<HBBf")
_RESET = struct.Struct("<If")
PAYLOAD_BYTES = 8


@dataclass(frozen=True)
class Frame:
    """One protocol frame (for RESET, ``seq`` is the run's seed and ``value`` the sampling rate)."""

    type: MsgType
    seq: int = 0
    channel: int = 0
    flags: int = 0
    value: float = 0.0

    def payload(self) -> bytes:
        if self.type == MsgType.RESET:
            return _RESET.pack(self.seq % 2**32, self.value)
        return _BODY.pack(self.seq % 2**16, self.channel, self.flags, self.value)

    @classmethod
    def decode(cls, type_code: int, payload: bytes) -> Frame:
        """Parse a frame; raises ValueError for an unknown type or a payload of the wrong size."""
        kind = MsgType(type_code)
        if len(payload) != PAYLOAD_BYTES:
            raise ValueError(f"payload of {len(payload)} bytes, expected {PAYLOAD_BYTES}")
        if kind == MsgType.RESET:
            seed, fs = _RESET.unpack(payload)
            return cls(kind, seed, value=fs)
        seq, channel, flags, value = _BODY.unpack(payload)
        return cls(kind, seq, channel, flags, value)


# -- CAN: one frame per message, 11-bit identifier = node id and type -----------------------------
def can_id(node_id: int, kind: MsgType) -> int:
    """11-bit identifier ``node_id << 3 | type`` (node ids 0..255)."""
    return (node_id << 3) | int(kind)


def split_can_id(arbitration_id: int) -> tuple[int, int]:
    """(node id, type code) of an identifier made by :func:`can_id`."""
    return arbitration_id >> 3, arbitration_id & 0x7


# -- serial: SYNC, node id, type, 8 payload bytes, CRC-8 -------------------------------------------
SYNC = 0xA5
SERIAL_FRAME_BYTES = 3 + PAYLOAD_BYTES + 1


def crc8(data: bytes) -> int:
    """CRC-8, polynomial 0x07 (ATM), initial value 0, no reflection."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def encode_serial(node_id: int, frame: Frame) -> bytes:
    body = bytes((node_id, int(frame.type))) + frame.payload()
    return bytes((SYNC,)) + body + bytes((crc8(body),))


class SerialDecoder:
    """Streaming decoder: feed bytes as they arrive, get (node id, Frame) pairs; resyncs on bad data."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.errors = 0  # frames dropped for a bad CRC or an unknown type

    def feed(self, data: bytes) -> list[tuple[int, Frame]]:
        self._buf += data
        out: list[tuple[int, Frame]] = []
        while True:
            start = self._buf.find(SYNC)
            if start < 0:
                self._buf.clear()
                return out
            del self._buf[:start]
            if len(self._buf) < SERIAL_FRAME_BYTES:
                return out
            body, crc = bytes(self._buf[1 : SERIAL_FRAME_BYTES - 1]), self._buf[SERIAL_FRAME_BYTES - 1]
            try:
                if crc8(body) != crc:
                    raise ValueError("bad CRC")
                out.append((body[0], Frame.decode(body[1], body[2:])))
            except ValueError:
                self.errors += 1
                del self._buf[:1]  # resync on the next SYNC byte
                continue
            del self._buf[:SERIAL_FRAME_BYTES]


class Link(abc.ABC):
    """One end of a frame link (CAN bus or serial line), filtered to the frames this end receives.

    Transport failures raise :class:`~labrunner.errors.RigError`.
    """

    @abc.abstractmethod
    def send(self, frame: Frame) -> None:
        """Send one frame."""

    @abc.abstractmethod
    def recv(self, timeout: float) -> Frame | None:
        """The next frame for this end, or None after ``timeout`` [s]."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the transport."""
