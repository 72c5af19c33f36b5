"""A real rig on a serial line through pyserial (USB-UART of a microcontroller, or a pty in tests).

Frames are ``SYNC node type payload[8] crc8`` (:func:`~labrunner.rigs.transports.protocol.encode_serial`);
the decoder resynchronises on corrupted bytes. Port errors raise :class:`~labrunner.errors.RigError`.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Mapping
from typing import Any, Protocol

import serial

from labrunner.errors import RigError
from labrunner.rigs.schema import Param
from labrunner.rigs.transports.protocol import HOST_RECEIVES, Frame, Link, MsgType, SerialDecoder, encode_serial
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
    """One end of the protocol on a byte stream, receiving only the frame types in ``receives``."""

    def __init__(self, port: Port, node_id: int, receives: frozenset[MsgType]) -> None:
        self.port, self.node_id, self.receives = port, int(node_id), receives
        self._decoder = SerialDecoder()
        self._pending: collections.deque[Frame] = collections.deque()

    @classmethod
    def open(cls, parameters: Mapping[str, Any], receives: frozenset[MsgType]) -> SerialLink:
        try:
            port = serial.Serial(parameters["port"], parameters["baudrate"], timeout=0.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise RigError(f"cannot open serial port {parameters['port']!r}: {exc}") from exc
        return cls(port, parameters["node_id"], receives)

    def send(self, frame: Frame) -> None:
        try:
            self.port.write(encode_serial(self.node_id, frame))
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
            for node, frame in self._decoder.feed(data):
                if node == self.node_id and frame.type in self.receives:
                    self._pending.append(frame)
            if not self._pending and remaining <= 0.0:
                return None
        return self._pending.popleft()

    def close(self) -> None:
        self.port.close()


class SerialRig(RemoteRig):
    """A rig whose firmware speaks the labrunner protocol on a serial line (B = 1)."""

    KIND = "serial"
    TRANSPORT = {
        "port": Param("/dev/ttyUSB0", "", "serial device (or a pty for the emulator)"),
        "baudrate": Param(115_200, "bit/s", "line speed", lo=1),
    }

    @classmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> SerialLink:
        return SerialLink.open(parameters, HOST_RECEIVES)
