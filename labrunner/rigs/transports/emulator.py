"""The emulated device: the firmware's reference behaviour, serving a simulated twin over a link.

:class:`Emulator` is the firmware's main loop in a thread: it receives host frames and calls the
handler registered for their kind in :attr:`Emulator.handlers`, and between frames it runs the
periodic :attr:`Emulator.tasks` (each returns the monotonic time it next wants to run). The core
here serves what every device does (``docs/protocol.md``): HELLO → IDENTITY, HEARTBEAT → STATUS,
SAFE (the safe input latched until the next run; a host-loop clock keeps ticking so the host
can log the rig coming to rest, until STOP or the watchdog), STOP (idle), the watchdog armed by a
run's set-up, a STATUS
heartbeat every :data:`STATUS_PERIOD_S` while running. The watchdog measures host silence in the
device's own running time: frames are taken before the timer tasks judge, and time the loop was
held up (it woke over :data:`HELD_UP_S` later than it asked: an emulator that a busy or virtual
machine paused) does not count. The loop placements install their own
handlers: :mod:`.hostloop_device` (SETUP, INPUT and the tick clock) always, and the modules named
in :data:`EXTENSIONS` (``"module:function"``, each called with the emulator) add theirs, e.g. the
device loop's bulk transfers.

Paced by default (the device's clock ticks in real time); ``paced=False`` ticks as soon as the
host commits an input, for fast tests. :class:`~.faults.LinkFaults` injects faults into what it sends.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import select
import threading
import time
import tty
from collections.abc import Callable

from labrunner.errors import LabrunnerError
from labrunner.rigs.base import Rig, RigConfig
from labrunner.rigs.config import config_from_dict
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.faults import FaultyLink, LinkFaults
from labrunner.rigs.transports.hostloop_device import install
from labrunner.rigs.transports.link import Link
from labrunner.rigs.transports.protocol import PROTOCOL_VERSION, End, Frame, Kind
from labrunner.rigs.transports.realtime import realtime

Handler = Callable[[Frame], None]
Task = Callable[[float], "float | None"]

STATUS_PERIOD_S = 0.1
HELD_UP_S = 0.001  # a loop that wakes this much later than it asked was held up (not host silence)
FIRMWARE_ID = 0x4C520001  # "LR", emulator build 1
EXTENSIONS: list[str] = ["labrunner.rigs.device.emulated:install"]  # "module:function" installers of further handlers


class Emulator:
    """Serve ``rig`` behind ``link`` until :meth:`stop`; ``errors`` collects exceptions of the twin."""

    def __init__(
        self,
        rig: Rig,
        link: Link,
        *,
        paced: bool = True,
        faults: LinkFaults | None = None,
        extensions: list[str] | None = None,
        realtime: bool = False,
    ) -> None:
        faults = faults or LinkFaults()
        self.rig, self.paced, self.faults = rig, paced, faults
        self.realtime = realtime  # ask for SCHED_FIFO in the firmware thread; False after start if not granted
        self.link: Link = FaultyLink(link, faults) if faults.any else link
        self.state = m.DeviceState.IDLE
        self.ticking = False  # a host-loop run's clock runs (in RUNNING and, holding the safe input, in SAFE)
        self.last_error = m.ErrorCode.NONE
        self.seq = 0  # the current tick, for STATUS and ERROR
        self.watchdog_s = float("inf")
        self.rejected = 0  # protocol-level rejects since the run's set-up (the link's drops come on top)
        self.late = 0
        self.safe_at: float | None = None  # monotonic time the device last went safe
        self.errors: list[BaseException] = []
        self.capabilities = m.Capability.HOST_LOOP | (m.Capability.CAN_FD if link.max_payload > 8 else 0)
        self.handlers: dict[Kind, Handler] = {
            Kind.HELLO: self._hello,
            Kind.HEARTBEAT: lambda f: self.send_status(),
            Kind.SAFE: self._safe,
            Kind.STOP: self._stop_run,
        }
        self.tasks: list[Task] = [self._watchdog, self._heartbeat]
        self._link_rejects_at_setup = 0
        self._fault: m.ErrorCode | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="labrunner-emulator", daemon=True)
        self._t0 = time.monotonic()
        self._last_rx = self._last_status = self._t0
        self._held_s = 0.0  # time the loop itself was held up since the last host frame
        self._die_at = float("inf")  # set when the first run begins (arm_death)
        install(self)
        for target in EXTENSIONS if extensions is None else extensions:
            module, _, function = target.partition(":")
            getattr(importlib.import_module(module), function)(self)

    def start(self) -> Emulator:
        # the firmware boots: its twin loads and computes what a set-up needs now (its modules, the
        # motor's transition matrices), so that no run's first tick waits for it past y_0's deadline or
        # the host's DEAD_S (scipy.linalg's import, when the motor used it, took ~0.5 s on a loaded machine)
        self.rig.reset(1, [0], float(self.rig.info.fs_default))
        self._started = threading.Event()
        self._thread.start()
        self._started.wait(2.0)
        return self

    def is_alive(self) -> bool:
        """Whether the firmware loop still runs (it ends when its link fails or it dies)."""
        return self._thread.is_alive()

    def stop(self, close_link: bool = True) -> None:
        """Stop serving (the device is gone); close its end of the link."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        if close_link:
            self.link.close()

    def inject_fault(self, code: m.ErrorCode = m.ErrorCode.DEVICE_FAULT) -> None:
        """Make the device report ``code`` (and go safe) at its next host frame, like a driver fault."""
        self._fault = code

    def __enter__(self) -> Emulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- services for the handlers -------------------------------------------------------------
    def begin_run(self, watchdog_s: float) -> None:
        """A run was set up: arm the watchdog, clear the run's counters, state RUNNING."""
        self.state, self.last_error, self.seq, self.ticking = m.DeviceState.RUNNING, m.ErrorCode.NONE, 0, True
        self.watchdog_s, self.rejected, self.late = float(watchdog_s), 0, 0
        self._link_rejects_at_setup = self._link_rejects()
        self._last_rx = self._last_status = time.monotonic()
        self._held_s = 0.0
        self.arm_death()

    def arm_death(self) -> None:
        """A run began: the first one starts the fault injection's ``die_after_s`` clock."""
        if self._die_at == float("inf"):
            self._die_at = time.monotonic() + self.faults.die_after_s
            if isinstance(self.link, FaultyLink):
                self.link.silent_from = self._die_at

    def go_safe(self) -> None:
        if self.state == m.DeviceState.RUNNING:
            self.rig.safe_state()
            self.state, self.safe_at = m.DeviceState.SAFE, time.monotonic()

    def error(self, code: m.ErrorCode, detail: float = 0.0, go_safe: bool = True) -> None:
        if go_safe:
            self.go_safe()
        self.last_error = code
        self.link.send(m.pack(m.Error(int(code), self.seq, detail)))

    def send_status(self) -> None:
        rejected = self.rejected + self._link_rejects() - self._link_rejects_at_setup
        self.link.send(
            m.pack(
                m.Status(
                    int(self.state),
                    int(self.last_error),
                    min(rejected, 0xFFFF),
                    min(self.late, 0xFFFF),
                    self.seq % 2**16,
                )
            )
        )
        self._last_status = time.monotonic()

    def identity(self) -> m.Identity:
        info = self.rig.info
        kind = m.DeviceKind.__members__.get(info.kind.upper(), m.DeviceKind.OTHER)
        return m.Identity(
            PROTOCOL_VERSION,
            int(kind),
            len(info.inputs),
            len(info.outputs),
            int(self.capabilities),
            float(info.fs_range[1]),
            FIRMWARE_ID,
        )

    # -- firmware loop ---------------------------------------------------------------------------
    def _serve(self) -> None:
        with realtime() if self.realtime else contextlib.nullcontext(False) as granted:
            self.realtime = granted
            self._started.set()
            self._loop()

    def _loop(self) -> None:
        faulty = self.link if isinstance(self.link, FaultyLink) else None
        while not self._stop.is_set():
            # the tasks judge the time the loop woke, after every frame that had arrived by then: as
            # firmware's receive interrupt queues frames before its timer tasks run, the watchdog
            # never trips over a frame that is waiting, however long the loop was held up
            now = time.monotonic()
            try:
                while (pending := self.link.recv(0.0)) is not None:
                    self._dispatch(pending)
            except LabrunnerError as exc:
                self.errors.append(exc)
                return
            except (OSError, ValueError):
                if self._stop.is_set():
                    return  # stop() closed the link under a loop that outlived its join (a long task)
                raise
            if now >= self._die_at:
                return  # the board lost power: silent from now on
            wake = now + 0.01
            try:
                for task in self.tasks:
                    due = task(now)
                    if due is not None:
                        wake = min(wake, due)
                if faulty is not None:
                    faulty.pump()
                    wake = min(wake, faulty.next_due() or wake)
                frame = self.link.recv(max(0.0, wake - time.monotonic()))
            except LabrunnerError as exc:  # the host end went away
                self.errors.append(exc)
                return
            if (late := time.monotonic() - wake) > HELD_UP_S:
                self._held_s += late
            if frame is not None:
                self._dispatch(frame)

    def _dispatch(self, frame: Frame) -> None:
        self._last_rx, self._held_s = time.monotonic(), 0.0
        try:
            if self._fault is not None:
                code, self._fault = self._fault, None
                self.error(code)
                return
            handler = self.handlers.get(frame.kind)
            if handler is None:
                self.rejected += 1
                self.error(m.ErrorCode.UNSUPPORTED, float(frame.kind), go_safe=False)
                return
            handler(frame)
        except LabrunnerError as exc:
            self.errors.append(exc)
        except Exception as exc:  # a twin failure is reported like a device fault
            self.errors.append(exc)
            self.error(m.ErrorCode.DEVICE_FAULT)

    def _link_rejects(self) -> int:
        c = self.link.counters
        return c.malformed + c.spoofed + c.crc_errors

    # -- core handlers and tasks -----------------------------------------------------------------
    def _hello(self, frame: Frame) -> None:
        if m.unpack(frame).version != PROTOCOL_VERSION:
            self.error(m.ErrorCode.VERSION, float(PROTOCOL_VERSION), go_safe=False)
        for record in m.identity_frames(self.identity()):
            self.link.send(record)

    def _safe(self, frame: Frame) -> None:
        if self.state != m.DeviceState.IDLE:
            self.go_safe()
        self.send_status()

    def _stop_run(self, frame: Frame) -> None:
        self.end_run()
        self.send_status()

    def end_run(self) -> None:
        """STOP, or a device-loop run beginning: the safe input, the host loop's clock and watchdog stopped, idle."""
        if self.state != m.DeviceState.IDLE:
            self.rig.safe_state()
            self.state = m.DeviceState.IDLE
        self.ticking, self.watchdog_s = False, float("inf")

    def _watchdog(self, now: float) -> float | None:
        silent = now - self._last_rx - self._held_s  # the device's own hold-ups are nobody's silence
        if self.state == m.DeviceState.SAFE and self.ticking and silent > self.watchdog_s:
            self.ticking = False  # safe, and nobody listens: stop sending measurements
        if self.state != m.DeviceState.RUNNING:
            return None
        if silent > self.watchdog_s:
            self.error(m.ErrorCode.WATCHDOG, silent)
            return None
        return self._last_rx + self._held_s + self.watchdog_s

    def _heartbeat(self, now: float) -> float | None:
        if self.state != m.DeviceState.RUNNING:
            return None
        if now - self._last_status >= STATUS_PERIOD_S:
            self.send_status()
        return self._last_status + STATUS_PERIOD_S


def twin_for(config: RigConfig) -> Rig:
    """The sim twin a remote rig file describes: its ``device`` kind with ``[parameters.model]``."""
    p = config.parameters
    return load_rig(
        config_from_dict({"rig": {"kind": p["device"], "name": config.name}, "parameters": dict(p["model"])})
    )


def device_link(config: RigConfig) -> Link:
    """The device's end of the link a ``can`` or ``serial`` rig file names."""
    if config.kind == "can":
        from labrunner.rigs.transports.can import CanLink

        return CanLink.open(config.parameters, End.DEVICE)
    from labrunner.rigs.transports.serial import SerialLink

    return SerialLink.open(config.parameters, End.DEVICE)


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


def pty_link(node_id: int) -> tuple[str, Link]:
    """A new pty pair: the name of the host's end and the device's link on the other end."""
    from labrunner.rigs.transports.serial import SerialLink

    master, slave = os.openpty()
    tty.setraw(slave)
    return os.ttyname(slave), SerialLink(PtyPort(master, slave), node_id, End.DEVICE)


def serve_on_pty(rig: Rig, node_id: int = 1, **options) -> tuple[str, Emulator]:
    """Serve ``rig`` on a new pty pair; return the port name for a serial rig and the running emulator."""
    name, link = pty_link(node_id)
    return name, Emulator(rig, link, **options).start()
