"""The emulated device's loop on board: the device-loop handlers of the firmware emulator.

:func:`install` (named in :data:`labrunner.rigs.transports.emulator.EXTENSIONS`) registers the
bulk kinds in the emulator's dispatch table and adds DEVICE_LOOP to its capabilities. A complete
run description runs at once, inside the handler, through the firmware's reference executor on
the emulator's twin: the device is busy with the run and its upload, reading its link itself
(ACKs; HEARTBEAT, HELLO and the like go to the emulator's own handlers; SAFE or STOP end the run).
The run's clock is virtual (see :mod:`labrunner.rigs.device.executor`): pacing does not apply.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib

from labrunner.rigs.device import executor, session
from labrunner.rigs.device.description import VERSION
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.faults import FaultyLink
from labrunner.rigs.transports.protocol import Frame, Kind

_IN = {Kind.BULK_TO_DEVICE: session.TO_DEVICE, Kind.BULK_ACK: session.ACK}
_OUT = {session.TO_HOST: Kind.BULK_TO_HOST, session.ACK: Kind.BULK_ACK}


class DeviceLoop:
    """The device-loop service of one emulator."""

    def __init__(self, emulator) -> None:
        self.emulator = emulator
        #: controller key → factor: a deliberately wrong law (``labrunner emulate --fault-law``)
        self.law_fault: dict[str, float] = {}
        #: protocol faults a broken firmware might have (``labrunner emulate --fault-protocol``:
        #: no-crc-check, any-version, ignore-stop, no-watchdog)
        self.protocol_faults: set[str] = set()
        #: the law in IEEE single precision (``labrunner emulate --float32``; announced as FLOAT32)
        self.float32 = False
        self.session = session.DeviceSession(self._send, self._recv, emulator.link.max_payload, self._execute)

    def on_frame(self, frame: Frame) -> None:
        self.session.on_message(_IN[frame.kind], frame.payload)

    def _send(self, kind: str, payload: bytes) -> None:
        self.emulator.link.send(Frame(_OUT[kind], payload))

    def _recv(self, timeout: float) -> tuple[str | None, bytes] | None:
        link = self.emulator.link
        if isinstance(link, FaultyLink):
            link.pump()  # delayed frames of the fault injection go out while the device is busy
        frame = link.recv(timeout)
        if frame is None:
            return None
        if frame.kind in _IN:
            return _IN[frame.kind], frame.payload
        self.emulator.seq = self.session.ticks_done  # STATUS's seq during a run: the ticks done
        self.emulator._dispatch(frame)  # HELLO, HEARTBEAT, SAFE, STOP: the core's answers
        stop = frame.kind in (Kind.SAFE, Kind.STOP) and "ignore-stop" not in self.protocol_faults
        return (session.STOP if stop else None), frame.payload

    def _execute(self, data: bytes, hook, on_accept, tick) -> executor.DeviceRun:
        emulator = self.emulator
        emulator.end_run()  # a host-loop run set up before ends here, its clock and watchdog with it

        def accepted(description) -> None:
            emulator.state, emulator.seq = m.DeviceState.RUNNING, 0
            if "no-watchdog" in self.protocol_faults:
                description = dataclasses.replace(description, watchdog_s=float("inf"))
            emulator.arm_death()
            on_accept(description)

        data = self._broken(data)
        try:
            run = executor.execute_document if self.float32 else executor.execute
            return run(data, emulator.rig, hook, accepted, tick, self.law_fault)
        finally:
            emulator.state = m.DeviceState.IDLE

    def _broken(self, data: bytes) -> bytes:
        """The description as a firmware with :attr:`protocol_faults` would take it."""
        if len(data) < 8 or not self.protocol_faults & {"no-crc-check", "any-version"}:
            return data
        body = bytearray(data[:-4])
        if "any-version" in self.protocol_faults:
            struct.pack_into("<H", body, 4, VERSION)
        return bytes(body) + struct.pack("<I", zlib.crc32(body))


def install(emulator) -> DeviceLoop:
    """Serve the device loop on ``emulator``: BULK_TO_DEVICE and BULK_ACK handlers, DEVICE_LOOP capability."""
    service = DeviceLoop(emulator)
    emulator.handlers[Kind.BULK_TO_DEVICE] = service.on_frame
    emulator.handlers[Kind.BULK_ACK] = service.on_frame
    emulator.capabilities |= m.Capability.DEVICE_LOOP
    emulator.device_loop = service
    return service


def use_float32(emulator) -> None:
    """Run the device loop's laws in float32 and say so in IDENTITY (capabilities bit FLOAT32)."""
    emulator.device_loop.float32 = True
    emulator.capabilities |= m.Capability.FLOAT32
