"""A real rig behind a frame link: the host side of the protocol's host loop (``loop = "host"``, B = 1).

The device is the clock (``docs/protocol.md`` § Host loop): SETUP starts a run and the device
samples y_0; ``step(u)`` sends u_k (INPUT frames, COMMIT on the last channel) and blocks until the
device's tick k+1 is complete (every output channel and the tick's trailer). A tick whose input
missed its deadline arrives flagged LATE (the device held u_{k−1}); the host counts and lists it,
and more than ``max_late_ticks`` late ticks in a row fail the run (the link cannot carry this
rate). Stale, duplicate and out-of-range measurements are counted and ignored; a tick with a
channel missing is never committed: the run fails, as it does when a channel arrives twice with
different values (old frames replayed) or the device's clock goes back (a reset, a replay): link
faults, never read as data (a |du/dt| abort) or as time (a +4295 s wrap). A missing answer within ``timeout_s + 1/f_s``,
a dead transport or an ERROR frame raises :class:`~labrunner.errors.RigError`, and the rig goes
to its safe state first (SAFE, best effort: if it cannot be sent, the device's watchdog takes over).

Rig files of the remote kinds (``can``, ``serial``) name the ``device`` kind whose signals,
limits and nominal constants the rig has (``[parameters.model]`` holds that kind's parameters);
``RigInfo.kind`` is the device kind and ``RigInfo.simulated`` is False.
"""

from __future__ import annotations

import abc
import contextlib
import threading
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np

from labrunner.errors import InvalidParameter, RigError
from labrunner.rigs.base import Faults, Rig, RigConfig, RigInfo
from labrunner.rigs.config import rig_info
from labrunner.rigs.kinds import rig_class, rig_kinds
from labrunner.rigs.schema import Param, validate_section
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.diagnostics import DeviceReport, HostCounters, diagnostics_record
from labrunner.rigs.transports.keepalive import Keepalive
from labrunner.rigs.transports.link import Link, LinkCounters
from labrunner.rigs.transports.protocol import NODE_MAX, NODE_MIN, PROTOCOL_VERSION, Kind
from labrunner.rigs.transports.realtime import realtime

SETUP_ANSWER_S = 0.5  # longest wait for y_0 after SETUP (a device may reset its hardware first)
#: Longest device time [s] between two ticks read as time passing; a longer step of the u32 µs
#: clock is the clock going back (a device reset to 0 a second into a run steps 4294 s forward).
CLOCK_STEP_MAX_S = 60.0
DEFAULT_LOOP = {"dcmotor": "host", "valve": "device", "plate": "device"}

COMMON = {
    "device": Param("dcmotor", "", "the kind of rig behind the link (any registered kind that is not itself remote)"),
    "node_id": Param(1, "", "the device's node id (0 is CANopen NMT; ids stay below 0x7F0)", lo=NODE_MIN, hi=NODE_MAX),
    "loop": Param(
        "",
        "",
        "where the closed loop runs: host (B = 1 over the link) or device; "
        "empty: host for dcmotor, device for valve and plate",
        choices=("", "host", "device"),
    ),
    "timeout_s": Param(
        0.1, "s", "longest wait for a measurement beyond one sample period", lo=0.0, lo_open=True, hi=60.0
    ),
    "watchdog_periods": Param(10.0, "1", "device watchdog in sample periods, sent in SETUP", lo=2.0, hi=1e6),
    "max_late_ticks": Param(10, "", "late ticks in a row that fail a host-loop run", lo=1, hi=1_000_000),
    "realtime": Param(
        False, "", "run the host loop's thread at SCHED_FIFO priority (root or CAP_SYS_NICE; ignored where not granted)"
    ),
    "reference_table": Param(
        False,
        "",
        "device loop: send the reference as a sample table read by tick index (firmware without "
        "the setpoints, steps and sine trajectory types)",
    ),
    "handshake_timeout_s": Param(0.5, "s", "longest wait for the device's IDENTITY", lo=0.0, lo_open=True, hi=60.0),
    "dead_s": Param(
        1.0,
        "s",
        "device loop: no bulk frame from the device for this long and it is dead or hung (the protocol's 1 s; "
        "longer only for a device in an emulator that a loaded host starves, as QEMU)",
        lo=0.5,
        hi=60.0,
    ),
    "max_consecutive_failures": Param(
        3, "", "points in a row that fail on the rig before the campaign stops", lo=1, hi=1_000_000
    ),
}


class WrongDevice(RigError):
    """The device answered the handshake but is not the rig file's (protocol version, kind, channels)."""


class RemoteRig(Rig):
    """Host side of the rig protocol over any :class:`Link`; subclasses open the link from a rig file."""

    KIND: ClassVar[str]
    TRANSPORT: ClassVar[Mapping[str, Param]]

    def __init__(self, info: RigInfo, link: Link, parameters: Mapping[str, Any], faults: Faults | None = None) -> None:
        super().__init__(info, faults)
        self.link = link
        self.parameters = dict(parameters)
        self.timeout_s = float(parameters["timeout_s"])
        self.loop = parameters["loop"]
        self.identity: m.Identity | None = None
        self.host = HostCounters()
        self.device = DeviceReport()
        self._link_at_setup = LinkCounters()
        self._seq = 0
        self._late_run = 0
        self._heartbeat = 0
        self._heartbeat_lock = threading.Lock()  # the loop's thread and the keepalive thread both send them
        self._keepalive = Keepalive(self._send_heartbeat, fifo=bool(parameters["realtime"]))
        self._realtime: contextlib.ExitStack | None = None  # SCHED_FIFO held from the first reset to close
        self._device_fault = False  # the device reported ERROR DEVICE_FAULT (recover() refuses to go on)
        self._clock: list[float] = []  # the device's timestamp of each tick of the run [s], u32 µs unwrapped

    # -- the Rig contract (no noise, no per-run parameters: the base class's defaults) ------------
    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        """The link's keys, and ``[parameters.model]`` validated by the ``device`` kind's own schema."""
        raw = dict(raw)
        model = raw.pop("model", {})
        p = validate_section({**COMMON, **cls.TRANSPORT}, raw, path)
        try:
            device = rig_class(p["device"]) if p["device"] in rig_kinds() else None
        except InvalidParameter as exc:  # registered, but its module does not import here
            raise InvalidParameter(f"{path}.device", exc.message) from None
        if device is None or issubclass(device, RemoteRig):
            raise InvalidParameter(f"{path}.device", f"must be one of {device_kinds()}, got {p['device']!r}")
        if not isinstance(model, Mapping):
            raise InvalidParameter(f"{path}.model", f"must be a table, got {model!r}")
        p["model"] = device.validate_parameters(model, f"{path}.model")
        p["loop"] = p["loop"] or DEFAULT_LOOP.get(p["device"], "host")
        return p

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        info = rig_class(parameters["device"]).nominal_info(name, description, parameters["model"])
        return replace(info, simulated=False, description=description or f"{info.kind} over {cls.KIND}")

    @classmethod
    def from_config(cls, config: RigConfig) -> RemoteRig:
        p = config.parameters
        return cls(rig_info(config), cls.open_link(p), p, config.faults)

    @classmethod
    @abc.abstractmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> Link:
        """Open the transport named by validated ``parameters`` (raises RigError)."""

    # -- handshake and diagnostics -------------------------------------------------------------
    def handshake(self, attempts: int = 3) -> m.Identity:
        """HELLO → IDENTITY (HELLO again, up to ``attempts`` times, while a record is missing);
        checks version, device kind and channel counts (RigError on a mismatch or no answer)."""
        self._drain()
        records: dict[int, bytes] = {}
        wait = float(self.parameters["handshake_timeout_s"]) / attempts
        for _ in range(attempts):
            self._send(m.hello())
            deadline = time.monotonic() + wait
            while len(records) < m.IDENTITY_RECORDS and (frame := self._recv(deadline)) is not None:
                if frame.kind == Kind.IDENTITY:
                    record = m.unpack(frame)
                    records[record.index] = record.value
                elif frame.kind == Kind.ERROR:
                    self._device_error(m.unpack(frame))
            if len(records) == m.IDENTITY_RECORDS:
                break
        else:
            self._fail(f"no complete IDENTITY answer to {attempts} HELLOs within {wait * attempts:.3g} s")
        ident = m.identity_from(records)
        kind = int(m.DeviceKind.__members__.get(self.info.kind.upper(), m.DeviceKind.OTHER))
        wrong = [
            f"{what} {got} (expected {want})"
            for what, got, want in (
                ("protocol version", ident.version, PROTOCOL_VERSION),
                ("device kind", ident.device_kind, kind),
                ("inputs", ident.n_inputs, len(self.info.inputs)),
                ("outputs", ident.n_outputs, len(self.info.outputs)),
            )
            if got != want
        ]
        if wrong:
            self.safe_state()
            raise WrongDevice(f"rig {self.info.name!r}: the device reports " + ", ".join(wrong))
        self.identity = ident
        return ident

    def diagnostics(self) -> dict[str, Any]:
        """This run's ``diagnostics`` record (see :mod:`.diagnostics`)."""
        now, then = self.link.counters.as_dict(), self._link_at_setup.as_dict()
        return diagnostics_record(
            {k: now[k] - then[k] for k in now},
            self.host,
            self.device,
            loop=self.loop,
            firmware_id=self.identity.firmware_id if self.identity else None,
        )

    def device_clock(self) -> np.ndarray:
        """The device's timestamp of each tick of the last host-loop run [s since its tick 0]."""
        return np.array(self._clock)

    def ping(self, stale_errors: bool = False) -> float:
        """Round trip [s] of one HEARTBEAT to the device's STATUS answer (RigError after ``timeout_s``).

        Frames from one sender arrive in order, so everything before the answer is older than the
        HEARTBEAT; with ``stale_errors`` an ERROR among them (of an earlier run) is counted stale."""
        with self._heartbeat_lock:
            self._heartbeat += 1
            frame = m.pack(m.Heartbeat(self._heartbeat))
        t0 = time.perf_counter()
        self._send(frame)
        deadline = time.monotonic() + self.timeout_s
        while True:
            frame = self._recv_until(deadline, f"no STATUS answer to HEARTBEAT within {self.timeout_s:g} s")
            if frame.kind == Kind.STATUS:
                self._status(m.unpack(frame))
                return time.perf_counter() - t0
            if frame.kind == Kind.ERROR:
                if not stale_errors:
                    self._device_error(m.unpack(frame))
                self.host.stale += 1

    def keepalive(self) -> None:
        """Send a HEARTBEAT if the host sent nothing for half a watchdog period (call while idle)."""
        if time.monotonic() - self._keepalive.last_send > 0.5 * self._watchdog_s():
            try:
                self._send_heartbeat()
            except RigError as exc:
                self._fail(str(exc))

    def _send_heartbeat(self) -> None:
        """One counted HEARTBEAT (from the loop's thread or the keepalive thread; RigError on a dead link)."""
        with self._heartbeat_lock:
            self._heartbeat += 1
            self.host.heartbeats_sent += 1
            frame = m.pack(m.Heartbeat(self._heartbeat))
        self.link.send(frame)
        self._keepalive.last_send = time.monotonic()

    def recover(self) -> None:
        """After a failed run: SAFE again, a fresh handshake and a STATUS that is not *running*.
        Raises RigError (the campaign stops) when the device does not answer, still runs, or
        failed by its own protection (ERROR DEVICE_FAULT)."""
        if self._device_fault:
            raise RigError(
                f"rig {self.info.name!r}: the device reported DEVICE_FAULT (its own protection); check the rig"
            )
        try:
            self.link.send(m.pack(m.Safe(self._seq)))
            self.identity = None
            self.handshake()
            for attempt in range(3):  # as many tries as the handshake's HELLOs: a lossy link loses answers
                try:
                    self.ping(stale_errors=True)
                    break
                except RigError:
                    if attempt == 2:
                        raise
        except WrongDevice as exc:  # it answered: alive, but not the device the rig file describes
            raise RigError(
                f"{exc}; after the failure the device answers the handshake but is not the rig file's device "
                "(check the rig file, the node id and the wiring)"
            ) from None
        except RigError as exc:
            raise RigError(
                f"{exc}; after the failure the device does not answer a fresh handshake: it may be dead or "
                "hung, and the rig may not be in its safe state"
            ) from None
        if self.device.state == m.DeviceState.RUNNING:
            self._fail("after the failure and a SAFE the device still reports a running loop")

    def run_on_device(self, points, *, fs: float, duration: float, seeds, rig_safety=None) -> list:
        """Run ``points`` with the loop on the device (``loop = "device"``): one run description
        each, their results as RunResults (:mod:`labrunner.rigs.device.remote`)."""
        from labrunner.rigs.device.remote import run_on_device

        return run_on_device(self, points, fs=fs, duration=duration, seeds=seeds, rig_safety=rig_safety)

    # -- Rig hooks -----------------------------------------------------------------------------
    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        if batch != 1:
            raise InvalidParameter("batch", f"must be 1 for a real rig, got {batch}")
        if self.loop != "host":
            raise RigError(f"rig {self.info.name!r}: loop = {self.loop!r} is not served by the host loop")
        if self.parameters["realtime"] and self._realtime is None:
            self._realtime = contextlib.ExitStack()
            self._realtime.enter_context(realtime())
        if self.identity is None:
            self.handshake()
        if self.identity is not None and not self.identity.capabilities & m.Capability.HOST_LOOP:
            self._fail("the device does not serve the host loop (capabilities lack HOST_LOOP)")
        self._drain()
        self._keepalive.start()
        self.host, self.device = HostCounters(), DeviceReport()
        self.ping(stale_errors=True)  # in step: what the device sent before this run is behind us
        self._link_at_setup = replace(self.link.counters)
        self._seq, self._late_run, self._clock = 0, 0, []
        self._keepalive.arm(self._watchdog_s(), int(self.parameters["max_late_ticks"]) / self.fs)
        for frame in m.setup_frames(self.fs, self._watchdog_s(), int(seeds[0])):
            self._send(frame)
        return self._collect(0, 0)

    def _step(self, u: np.ndarray) -> np.ndarray:
        n = u.shape[1]
        for ch in range(n):
            self._send(m.pack(m.Input(self._seq, ch, m.FLAG_COMMIT if ch == n - 1 else 0, float(u[0, ch]))))
        self._seq = (self._seq + 1) % 2**16
        y = self._collect(self._seq, self.k + 1)
        self._keepalive.last_step = time.monotonic()
        return y

    def _enter_safe_state(self, safe: np.ndarray) -> None:
        if safe.any():
            self._keepalive.disarm()
            try:
                self.link.send(m.pack(m.Safe(self._seq)))
            except RigError:
                pass  # the device's watchdog puts it in its safe state when the host falls silent

    def _close(self) -> None:
        self._keepalive.close()
        try:
            self.link.send(m.pack(m.Stop(self._seq)))
        except RigError:
            pass
        self.link.close()
        if self._realtime is not None:
            self._realtime.close()

    # -- helpers -------------------------------------------------------------------------------
    def _watchdog_s(self) -> float:
        return float(self.parameters["watchdog_periods"]) / self.fs

    def _send(self, frame: m.Frame) -> None:
        try:
            self.link.send(frame)
        except RigError as exc:
            self._fail(str(exc))
        self._keepalive.last_send = time.monotonic()

    def _drain(self) -> None:
        """Drop what is left of an earlier run or handshake."""
        try:
            while self.link.recv(0.0) is not None:
                pass
        except RigError as exc:
            self._fail(str(exc))

    def _recv(self, deadline: float) -> m.Frame | None:
        """The next frame before ``deadline`` (monotonic), else None; a HEARTBEAT goes out while waiting."""
        while (remaining := deadline - time.monotonic()) > 0.0:
            try:
                frame = self.link.recv(min(remaining, 0.5 * self._watchdog_s()))
            except RigError as exc:
                self._fail(str(exc))
            if frame is not None:
                return frame
            self.keepalive()
        return None

    def _recv_until(self, deadline: float, what: str) -> m.Frame:
        """The next frame before ``deadline``; the rig fails with ``what`` when none comes."""
        frame = self._recv(deadline)
        if frame is None:
            self._fail(what)
        return frame

    def _collect(self, seq: int, tick: int) -> np.ndarray:
        """Every output channel and the trailer of tick ``seq`` (the run's tick ``tick``); see the
        module doc for the rules."""
        n = len(self.info.outputs)
        y = np.zeros((1, n))
        missing = set(range(n))
        limit = (self.timeout_s if tick else max(self.timeout_s, SETUP_ANSWER_S)) + 1.0 / self.fs
        deadline = time.monotonic() + limit
        while True:
            frame = self._recv_until(
                deadline,
                f"no complete measurement of tick {seq} within {limit:.3g} s (missing channels {sorted(missing)})",
            )
            if frame.kind == Kind.STATUS:
                self._status(m.unpack(frame))
                continue
            if frame.kind == Kind.ERROR:
                self._device_error(m.unpack(frame))
            if frame.kind != Kind.MEASUREMENT:
                continue
            msg = m.unpack(frame)
            age = (seq - msg.seq) % 2**16
            if 0 < age < 2**15:
                self.host.stale += 1
            elif age != 0:  # a later tick began: this one lost channels
                self.host.lost_ticks += 1
                self._fail(f"tick {seq} incomplete: channels {sorted(missing) or ['trailer']} lost")
            elif isinstance(msg, m.TickEnd):
                if missing:
                    self.host.lost_ticks += 1
                    self._fail(f"tick {seq} incomplete: channels {sorted(missing)} lost")
                self._tick_end(msg, tick)
                return y
            elif msg.channel >= n:
                self.host.bad_channel += 1
            elif msg.channel not in missing:
                self.host.duplicate += 1
                if not _same_value(msg.value, y[0, msg.channel]):  # not a repeat: one of them is old
                    self._fail(
                        f"link fault: tick {seq} channel {msg.channel} arrived twice with different values "
                        f"({y[0, msg.channel]:g}, then {msg.value:g}): the device replays old frames"
                    )
            else:
                y[0, msg.channel] = msg.value
                missing.discard(msg.channel)

    def _tick_end(self, msg: m.TickEnd, tick: int) -> None:
        late, overrun = bool(msg.flags & m.FLAG_LATE), bool(msg.flags & m.FLAG_OVERRUN)
        self.host.note_tick(tick, late, overrun)
        stamp = msg.timestamp_us * 1e-6
        if self._clock:
            stamp = self._clock[-1] + self._clock_step(msg, tick)
        self._clock.append(stamp)
        self.device.device_time_s = stamp
        self._late_run = self._late_run + 1 if late else 0
        if self._late_run > int(self.parameters["max_late_ticks"]):
            self._fail(
                f"{self._late_run} late ticks in a row at {self.fs:g} Hz: the host loop cannot keep "
                f'this rate over this link (lower fs, or loop = "device")'
            )

    def _clock_step(self, msg: m.TickEnd, tick: int) -> float:
        """The device time [s] from the previous tick to this one: its u32 µs timestamps differ
        modulo 2^32 (a wrap every 71.6 min is a small step). A step longer than
        :data:`CLOCK_STEP_MAX_S` (far beyond any tick the host waits for, or the device's watchdog)
        is not time passing but the device's clock going back — reset to 0, or old frames
        replayed — a link fault, never read as +4295 s."""
        previous = round(self._clock[-1] * 1e6) % 2**32
        step = ((msg.timestamp_us - previous) % 2**32) * 1e-6
        if step > CLOCK_STEP_MAX_S:
            self._fail(
                f"link fault: the device clock went from {self._clock[-1]:.6f} s to {msg.timestamp_us * 1e-6:.6f} s "
                f"at tick {tick} (a device reset, or old frames replayed)"
            )
        return step

    def _status(self, msg: m.Status) -> None:
        self.host.status_frames += 1
        self.device.state, self.device.last_error = msg.state, msg.last_error
        self.device.rejected, self.device.late = msg.rejected, msg.late

    def _device_error(self, msg: m.Error) -> None:
        self.host.device_errors += 1
        self._device_fault |= msg.code == m.ErrorCode.DEVICE_FAULT
        code = m.ErrorCode(msg.code).name if msg.code in m.ErrorCode._value2member_map_ else msg.code
        self._fail(f"device error {code} at tick {msg.seq} (detail {msg.detail:g})")

    def _fail(self, message: str) -> None:
        self.safe_state()
        raise RigError(f"rig {self.info.name!r}: {message}")


def _same_value(a: float, b: float) -> bool:
    """Equal values, NaN equal to NaN (a repeated frame, not a conflicting one)."""
    return a == b or (a != a and b != b)


def device_kinds() -> list[str]:
    """The kinds a remote rig's ``device`` may name: every registered kind that is not remote itself."""
    kinds = []
    for kind in rig_kinds():
        try:
            remote = issubclass(rig_class(kind), RemoteRig)
        except InvalidParameter:  # a kind whose module cannot be imported here cannot be a device
            continue
        if not remote:
            kinds.append(kind)
    return sorted(kinds)
