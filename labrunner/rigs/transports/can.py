"""A real rig on a CAN bus through python-can (``socketcan``, ``pcan``, ... or ``udp_multicast`` for tests).

Each protocol frame is one classic CAN frame with the 11-bit identifier ``node_id << 3 | type``
(:func:`~labrunner.rigs.transports.protocol.can_id`). Bus errors raise
:class:`~labrunner.errors.RigError`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import can

from labrunner.errors import RigError
from labrunner.rigs.schema import Param
from labrunner.rigs.transports.protocol import HOST_RECEIVES, PAYLOAD_BYTES, Frame, Link, MsgType, can_id, split_can_id
from labrunner.rigs.transports.remote import RemoteRig


class CanLink(Link):
    """One end of the protocol on a python-can bus, receiving only the frame types in ``receives``."""

    def __init__(self, bus: can.BusABC, node_id: int, receives: frozenset[MsgType]) -> None:
        self.bus, self.node_id, self.receives = bus, int(node_id), receives

    @classmethod
    def open(cls, parameters: Mapping[str, Any], receives: frozenset[MsgType]) -> CanLink:
        """Open ``can.Bus(interface, channel[, bitrate][, port])`` from validated rig parameters."""
        kwargs: dict[str, Any] = {"interface": parameters["interface"], "channel": parameters["channel"]}
        if parameters["bitrate"]:
            kwargs["bitrate"] = parameters["bitrate"]
        if parameters["port"]:
            kwargs["port"] = parameters["port"]
        try:
            bus = can.Bus(**kwargs)
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as exc:
            raise RigError(f"cannot open CAN bus {kwargs}: {exc}") from exc
        return cls(bus, parameters["node_id"], receives)

    def send(self, frame: Frame) -> None:
        msg = can.Message(arbitration_id=can_id(self.node_id, frame.type), data=frame.payload(), is_extended_id=False)
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
            node, code = split_can_id(msg.arbitration_id)
            if msg.is_extended_id or node != self.node_id or code not in self.receives or msg.dlc != PAYLOAD_BYTES:
                continue
            return Frame.decode(code, bytes(msg.data))

    def close(self) -> None:
        self.bus.shutdown()


class CanRig(RemoteRig):
    """A rig whose firmware speaks the labrunner protocol on a CAN bus (B = 1)."""

    KIND = "can"
    TRANSPORT = {
        "interface": Param("socketcan", "", "python-can interface: socketcan, pcan, kvaser, udp_multicast, virtual, ..."),
        "channel": Param("can0", "", "python-can channel (can0, PCAN_USBBUS1, a multicast group, ...)"),
        "bitrate": Param(500_000, "bit/s", "bus bit rate; 0 leaves the interface's setting", lo=0),
        "port": Param(0, "", "UDP port of the udp_multicast interface; 0 for its default", lo=0, hi=65535),
    }

    @classmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> CanLink:
        return CanLink.open(parameters, HOST_RECEIVES)
