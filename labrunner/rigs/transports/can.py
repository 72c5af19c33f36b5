"""A real rig on a CAN bus through python-can (``socketcan``, ``pcan``, ... or ``udp_multicast`` for tests).

Each frame is one CAN frame with the 11-bit identifier ``function_code << 7 | node_id``
(:func:`~labrunner.rigs.transports.protocol.can_id`): classic CAN (8-byte payloads) or, with
``fd = true``, CAN FD (bulk payloads up to 64 bytes, bit-rate switching). Without ``interface``
or ``channel`` in the rig file python-can's own configuration applies (``CAN_INTERFACE``,
``CAN_CHANNEL``, ``CAN_BITRATE``, ``~/.canrc``, ...). ``bitrate`` is passed to interfaces that set
the bus rate (pcan, kvaser, vector, ...); on socketcan the kernel owns it (``ip link set can0 type
can bitrate 500000``) and ``check-rig`` reports the rate read back from the interface. Bus errors
raise :class:`~labrunner.errors.RigError`; CAN error frames are counted and skipped.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import can
from can.util import dlc2len, len2dlc

from labrunner.errors import RigError
from labrunner.rigs.schema import Param
from labrunner.rigs.transports.link import Link
from labrunner.rigs.transports.protocol import End, Frame, Kind, can_id, split_can_id
from labrunner.rigs.transports.remote import RemoteRig

# interfaces whose bus rate python-can does not set (the OS or nothing owns it)
RATE_NOT_SET_BY_PYTHON_CAN = frozenset({"socketcan", "udp_multicast", "virtual"})


class CanLink(Link):
    """One end of the protocol on a python-can bus (see :class:`~.link.Link` for the contract)."""

    def __init__(self, bus: can.BusABC, node_id: int, end: End, fd: bool = False) -> None:
        super().__init__(node_id, end)
        self.bus, self.fd = bus, bool(fd)

    @property
    def max_payload(self) -> int:
        return 64 if self.fd else 8

    @classmethod
    def open(cls, parameters: Mapping[str, Any], end: End) -> CanLink:
        """Open ``can.Bus(...)`` from validated rig parameters (empty ones are left to python-can)."""
        kwargs: dict[str, Any] = {k: parameters[k] for k in ("interface", "channel") if parameters[k]}
        interface = parameters["interface"] or can.util.load_config().get("interface", "")
        if parameters["bitrate"] and interface not in RATE_NOT_SET_BY_PYTHON_CAN:
            kwargs["bitrate"] = parameters["bitrate"]
        if parameters["fd"]:
            kwargs["fd"] = True
            if parameters["data_bitrate"] and interface not in RATE_NOT_SET_BY_PYTHON_CAN:
                kwargs["data_bitrate"] = parameters["data_bitrate"]
        if parameters["port"]:
            kwargs["port"] = parameters["port"]
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            raise RigError(f"cannot open CAN bus {kwargs}: {exc}") from exc
        return cls(bus, parameters["node_id"], end, parameters["fd"])

    def _wire_payload(self, payload: bytes) -> bytes:
        return payload.ljust(dlc2len(len2dlc(len(payload))), b"\x00") if self.fd else payload

    def _send(self, kind: Kind, payload: bytes) -> None:
        msg = can.Message(
            arbitration_id=can_id(self.node_id, kind, self.end),
            data=payload,
            is_extended_id=False,
            is_fd=self.fd,
            bitrate_switch=self.fd,
        )
        try:
            self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            raise RigError(f"CAN send failed: {exc}") from exc

    def recv(self, timeout: float) -> Frame | None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                msg = self.bus.recv(max(0.0, deadline - time.monotonic()))
            except (can.CanError, OSError) as exc:
                raise RigError(f"CAN receive failed: {exc}") from exc
            if msg is None:
                return None
            frame = self._filter(msg)
            if frame is not None:
                return frame

    def _filter(self, msg: can.Message) -> Frame | None:
        if msg.is_error_frame:
            self.counters.error_frames += 1
            return None
        if msg.is_extended_id or msg.is_remote_frame:
            self.counters.foreign += 1
            return None
        try:
            node, kind, sender = split_can_id(msg.arbitration_id)
        except ValueError:
            if msg.arbitration_id & 0x7F == self.node_id:
                self.counters.malformed += 1
            else:
                self.counters.foreign += 1
            return None
        return self._accept(node, kind, sender, bytes(msg.data))

    def close(self) -> None:
        self.bus.shutdown()


class CanRig(RemoteRig):
    """A rig whose firmware speaks the labrunner protocol on a CAN bus (B = 1 host loop)."""

    KIND = "can"
    TRANSPORT = {
        "interface": Param(
            "",
            "",
            "python-can interface (socketcan, pcan, kvaser, udp_multicast, virtual, ...); "
            "empty: python-can's configuration",
        ),
        "channel": Param(
            "", "", "python-can channel (can0, PCAN_USBBUS1, a multicast group, ...); empty: python-can's configuration"
        ),
        "bitrate": Param(
            500_000,
            "bit/s",
            "the bus's (nominal) bit rate: set on pcan, kvaser, ...; on socketcan "
            "set by `ip link`; used by the link-load check",
            lo=10_000,
            hi=1_000_000,
        ),
        "fd": Param(False, "", "CAN FD frames (64-byte bulk payloads)"),
        "data_bitrate": Param(2_000_000, "bit/s", "CAN FD data-phase bit rate", lo=1_000_000, hi=8_000_000),
        "port": Param(0, "", "UDP port of the udp_multicast interface; 0 for its default", lo=0, hi=65535),
    }

    @classmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> CanLink:
        return CanLink.open(parameters, End.HOST)
