"""A real rig on a serial line through pyserial (USB-UART of a microcontroller, or a pty in tests).

Frames are COBS-encoded ``node code payload crc16`` ending in 0x00
(:mod:`~labrunner.rigs.transports.framing`); the decoder resynchronises at the next delimiter
after garbage and counts what it dropped. Port errors raise :class:`~labrunner.errors.RigError`.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Mapping
from typing import Any, Protocol

import serial

from labrunner.errors import RigError
from labrunner.rigs.schema import Param
from labrunner.rigs.transports.framing import SERIAL_MAX_PAYLOAD, SerialDecoder, encode_frame
from labrunner.rigs.transports.link import Link
from labrunner.rigs.transports.protocol import End, Frame, Kind, function_code, split_function_code
from labrunner.rigs.transports.remote import RemoteRig


class Port(Protocol):
    """What the link needs of a port: pyserial's ``Serial`` or the emulator's pty end."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


class SerialLink(Link):
    """One end of the protocol on a byte stream (see :class:`~.link.Link` for the contract)."""

    def __init__(self, port: Port, node_id: int, end: End) -> None:
        super().__init__(node_id, end)
        self.port = port
        self._decoder = SerialDecoder(self.counters)
        self._pending: collections.deque[Frame] = collections.deque()

    @property
    def max_payload(self) -> int:
        return SERIAL_MAX_PAYLOAD

    @classmethod
    def open(cls, parameters: Mapping[str, Any], end: End) -> SerialLink:
        try:
            port = serial.Serial(parameters["port"], parameters["baudrate"], timeout=0.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise RigError(f"cannot open serial port {parameters['port']!r}: {exc}") from exc
        return cls(port, parameters["node_id"], end)

    def _send(self, kind: Kind, payload: bytes) -> None:
        try:
            self.port.write(encode_frame(self.node_id, function_code(kind, self.end), payload))
        except (serial.SerialException, OSError) as exc:
            raise RigError(f"serial write failed: {exc}") from exc

    def recv(self, timeout: float) -> Frame | None:
        deadline = time.monotonic() + timeout
        while not self._pending:
            remaining = deadline - time.monotonic()
            try:
                self.port.timeout = max(0.0, remaining)
                data = self.port.read(1)  # wait for the first byte, then take what has arrived
                if data:
                    data += self.port.read(self.port.in_waiting)
            except (serial.SerialException, OSError) as exc:
                raise RigError(f"serial read failed: {exc}") from exc
            for node, code, payload in self._decoder.feed(data):
                try:
                    kind, sender = split_function_code(code)
                except ValueError:
                    self.counters.malformed += 1
                    continue
                frame = self._accept(node, kind, sender, payload)
                if frame is not None:
                    self._pending.append(frame)
            if not self._pending and remaining <= 0.0:
                return None
        return self._pending.popleft()

    def close(self) -> None:
        self.port.close()


class SerialRig(RemoteRig):
    """A rig whose firmware speaks the labrunner protocol on a serial line (B = 1 host loop)."""

    KIND = "serial"
    TRANSPORT = {
        "port": Param("/dev/ttyUSB0", "", "serial device (or the pty `labrunner emulate` prints)"),
        "baudrate": Param(115_200, "bit/s", "line speed (8N1: 10 bits per byte)", lo=1200, hi=12_000_000),
    }

    @classmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> SerialLink:
        return SerialLink.open(parameters, End.HOST)
