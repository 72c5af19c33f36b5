"""Device-firmware twin: serves a simulated rig (B = 1) over a frame link, in a thread.

It behaves as the rig protocol asks of real firmware (:mod:`~labrunner.rigs.transports.protocol`):
RESET starts a run and answers with the first measurement, a committed INPUT steps the twin by one
sample and answers with its measurement, SAFE holds the safe input until the next RESET, HEARTBEAT
is answered with STATUS, and a running device that hears nothing for ``watchdog_s`` goes safe on
its own and sends ERROR WATCHDOG. It answers as fast as it can (no real-time pacing): the host's
``step`` blocks on the answer exactly as it does on a device-clocked rig.

Used by the tests (CAN over ``udp_multicast``, serial over a pty pair) and to try a real-rig
campaign without hardware::

    python -m labrunner.rigs.transports.emulator rigs/dcmotor-can.toml
"""

from __future__ import annotations

import argparse
import os
import select
import threading
import time
import tty
from collections.abc import Sequence

import numpy as np

from labrunner.errors import LabrunnerError
from labrunner.rigs.base import Rig
from labrunner.rigs.base import RigConfig
from labrunner.rigs.config import config_from_dict, load_rig_config
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports.protocol import (
    DEVICE_RECEIVES,
    FLAG_COMMIT,
    FLAG_LAST,
    DeviceState,
    ErrorCode,
    Frame,
    Link,
    MsgType,
)


class Emulator:
    """Serve ``rig`` behind ``link`` until :meth:`stop`; ``errors`` collects exceptions of the twin."""

    def __init__(self, rig: Rig, link: Link, *, watchdog_s: float = 0.5) -> None:
        self.rig, self.link, self.watchdog_s = rig, link, float(watchdog_s)
        self.state = DeviceState.IDLE
        self.last_error = ErrorCode.NONE
        self.errors: list[BaseException] = []
        self._u = np.zeros((1, len(rig.info.inputs)))
        self._seq = 0
        self._fault: ErrorCode | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="labrunner-emulator", daemon=True)
        self._t0 = time.monotonic()
        self._last_rx = self._t0

    def start(self) -> Emulator:
        self._thread.start()
        return self

    def stop(self, close_link: bool = True) -> None:
        """Stop serving (the device is gone); close its end of the link."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        if close_link:
            self.link.close()

    def inject_fault(self, code: ErrorCode = ErrorCode.DEVICE_FAULT) -> None:
        """Make the device report ``code`` (and go safe) at its next host frame, like a driver fault."""
        self._fault = code

    def __enter__(self) -> Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- firmware loop ---------------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.link.recv(0.005)
            except LabrunnerError as exc:  # the host end went away
                self.errors.append(exc)
                return
            now = time.monotonic()
            if frame is not None:
                self._last_rx = now
                try:
                    self._handle(frame)
                except Exception as exc:  # a twin failure is reported like a device fault
                    self.errors.append(exc)
                    self._error(ErrorCode.DEVICE_FAULT)
            elif self.state == DeviceState.RUNNING and now - self._last_rx > self.watchdog_s:
                self._error(ErrorCode.WATCHDOG)

    def _handle(self, frame: Frame) -> None:
        if self._fault is not None:
            code, self._fault = self._fault, None
            self._error(code)
            return
        if frame.type == MsgType.RESET:
            y = self.rig.reset(1, [frame.seq], float(frame.value))
            self.state, self._seq, self.last_error = DeviceState.RUNNING, 0, ErrorCode.NONE
            self._u = np.asarray([self.rig.info.safe_input], dtype=float)
            self._measure(y)
        elif frame.type == MsgType.INPUT:
            self._input(frame)
        elif frame.type == MsgType.SAFE:
            if self.state != DeviceState.IDLE:
                self.rig.safe_state()
                self.state = DeviceState.SAFE
            self._status()
        elif frame.type == MsgType.HEARTBEAT:
            self._status()

    def _input(self, frame: Frame) -> None:
        if self.state == DeviceState.IDLE:
            self._error(ErrorCode.NOT_RUNNING, go_safe=False)
            return
        if frame.channel >= self._u.shape[1]:
            self._error(ErrorCode.BAD_CHANNEL, float(frame.channel))
            return
        if frame.seq != (self._seq + 1) % 2**16:
            self._error(ErrorCode.SEQUENCE, float(frame.seq))
            return
        self._u[0, frame.channel] = frame.value
        if frame.flags & FLAG_COMMIT:
            self._seq = frame.seq
            self._measure(self.rig.step(self._u))

    def _measure(self, y: np.ndarray) -> None:
        n = y.shape[1]
        for ch in range(n):
            self.link.send(Frame(MsgType.MEASUREMENT, self._seq, ch, FLAG_LAST if ch == n - 1 else 0, float(y[0, ch])))

    def _status(self) -> None:
        t = time.monotonic() - self._t0
        self.link.send(Frame(MsgType.STATUS, self._seq, int(self.state), int(self.last_error), t))

    def _error(self, code: ErrorCode, detail: float = 0.0, go_safe: bool = True) -> None:
        if go_safe and self.state == DeviceState.RUNNING:
            self.rig.safe_state()
            self.state = DeviceState.SAFE
        self.last_error = code
        self.link.send(Frame(MsgType.ERROR, self._seq, int(code), 0, detail))


def twin_for(config: RigConfig) -> Rig:
    """The sim twin a remote rig file describes: its ``device`` kind with ``[parameters.model]``."""
    p = config.parameters
    return load_rig(config_from_dict({"rig": {"kind": p["device"], "name": config.name}, "parameters": dict(p["model"])}))


def device_link(config: RigConfig) -> Link:
    """The device's end of the link a ``can`` or ``serial`` rig file names."""
    if config.kind == "can":
        from labrunner.rigs.transports.can import CanLink

        return CanLink.open(config.parameters, DEVICE_RECEIVES)
    from labrunner.rigs.transports.serial import SerialLink

    return SerialLink.open(config.parameters, DEVICE_RECEIVES)


class PtyPort:
    """The master end of a pty as a port for :class:`~labrunner.rigs.transports.serial.SerialLink`.

    ``slave_fd`` stays open until :meth:`close`, so the master never reads EOF before the host
    opens the port by name.
    """

    def __init__(self, fd: int, slave_fd: int | None = None) -> None:
        self.fd, self.slave_fd = fd, slave_fd
        self.timeout: float | None = 0.0

    @property
    def in_waiting(self) -> int:
        return 4096 if select.select([self.fd], [], [], 0.0)[0] else 0

    def read(self, size: int = 1) -> bytes:
        if not select.select([self.fd], [], [], self.timeout)[0]:
            return b""
        return os.read(self.fd, size)

    def write(self, data: bytes) -> int:
        return os.write(self.fd, data)

    def close(self) -> None:
        os.close(self.fd)
        if self.slave_fd is not None:
            os.close(self.slave_fd)


def serve_on_pty(rig: Rig, node_id: int = 1, *, watchdog_s: float = 0.5) -> tuple[str, Emulator]:
    """Serve ``rig`` on a new pty pair; return the port name for a serial rig and the running emulator."""
    from labrunner.rigs.transports.serial import SerialLink

    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    emulator = Emulator(rig, SerialLink(PtyPort(master, slave), node_id, DEVICE_RECEIVES), watchdog_s=watchdog_s)
    return name, emulator.start()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Serve a rig file's device as a simulated twin on its bus.")
    parser.add_argument("rig", help="a can or serial rig file (its device kind and [parameters.model] are served)")
    parser.add_argument("--watchdog", type=float, default=0.5, help="device watchdog [s]")
    args = parser.parse_args(argv)
    config = load_rig_config(args.rig)
    emulator = Emulator(twin_for(config), device_link(config), watchdog_s=args.watchdog).start()
    print(f"serving {config.parameters['device']} twin for {config.source}; Ctrl-C stops")
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        emulator.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
