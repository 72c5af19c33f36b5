"""``labrunner conform RIG.toml``: does a device-loop device run the documented laws and protocol?

Checks, each passed or failed with a one-line detail (docs/control-laws.md, docs/device-loop.md):

* ``handshake``: IDENTITY answers HELLO and announces DEVICE_LOOP;
* ``handshake`` also says which arithmetic the device announces (FLOAT32: float32, else float64);
  the vectors' law check uses that arithmetic's tolerance;
* ``vector <case>``: every conformance vector of the device's rig kind, run in the sensor-table
  mode (the device reads y[k] from the description, nothing moves): the device must log the
  table's y, the host's law check must pass on its rows — recomputed from the exact float64
  table, so the tolerance is float64 rounding in another order and the float32 of the logged
  values, far tighter than a plant run's — and the verdict must be the vector's;
* ``reject <what>``: a description with a bad CRC-32, another version, a bad magic, a wrong
  length, an unknown record type, an unknown controller kind or the wrong channel counts must be
  answered by REJECT;
* ``hello version``: a HELLO of another protocol version must be answered by ERROR VERSION;
* ``STOP mid-run``, ``SAFE mid-run``: the run must end *failed* soon after the host's STOP or
  SAFE, with the device no longer running;
* ``watchdog``: a host silent for longer than the description's watchdog must end the run *failed*.
  A device that completes the run instead may have outrun the silence (faster than real time:
  an emulator did, in 1 of 2 tries); it is tried once more on a run ten times the silence's span
  at the tick rate it showed, and fails only if it completes that one too.
"""

from __future__ import annotations

import math
import struct
import time
import zlib
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from labrunner.errors import RigError
from labrunner.rigs.base import RigConfig
from labrunner.rigs.device import blocks, description, lawcheck, session, vectors
from labrunner.rigs.device.host import to_result
from labrunner.rigs.device.remote import adapters
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.protocol import PROTOCOL_VERSION, Kind

STOP_AFTER_S = 0.5  #: the host's STOP / SAFE (or silence) starts this long after the run's first answer
ANSWER_S = 3.0  #: a stopped run's verdict must come within this long of the STOP
LONG_TICKS = 60_000  #: ticks of the run that STOP, SAFE and the watchdog interrupt
WATCHDOG_S = 1.0  #: the interrupted run's watchdog; the host stays silent for 2.5 × this
VERSION_PATIENCE = 4.0  #: the HELLO-version answer is awaited this many handshake timeouts (at least 3 s)


@dataclass(frozen=True)
class Check:
    """One conformance check: its name, whether it passed, and what was seen."""

    name: str
    passed: bool
    detail: str

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def cases_for(kind: str) -> list[str]:
    """The conformance vectors of a rig kind (``dcmotor``, ``valve``, ``plate``)."""
    return [name for name, case in vectors.CASES.items() if load_rig(case.rig).info.kind == kind]


def conform(config: RigConfig, cases: Sequence[str] | None = None, protocol: bool = True) -> list[Check]:
    """Every check against the device of the rig file ``config`` (a can or serial rig)."""
    rig = load_rig(config)
    with rig:
        try:
            ident = rig.handshake()
        except RigError as exc:
            return [Check("handshake", False, str(exc))]
        loop = bool(ident.capabilities & m.Capability.DEVICE_LOOP)
        arithmetic = lawcheck.arithmetic_of(ident.capabilities)
        checks = [
            Check(
                "handshake", loop,
                f"firmware {ident.firmware_id:#010x}, DEVICE_LOOP {'yes' if loop else 'no'}, laws in {arithmetic}",
            )
        ]  # fmt: skip
        if not loop:
            return checks
        names = list(cases) if cases is not None else cases_for(rig.info.kind)
        checks += [_vector(rig, name, arithmetic) for name in names]
        if protocol and names:
            base = vectors.build(vectors.CASES[names[0]])
            checks += [_reject(rig, what, bad, base.data) for what, bad in _broken(base.data)]
            checks.append(_hello_version(rig))
            case = vectors.CASES[names[0]]
            checks += [_interrupted(rig, case, how) for how in ("STOP", "SAFE", "watchdog")]
    return checks


def _run(rig, data: bytes, send_hook=None, recv_hook=None, like: bytes | None = None) -> tuple:
    """(verdict, rows, transfer) of one description on the device; RigError for a refusal or a dead
    link. ``like``: the good description a broken ``data`` was made from (its ticks and columns)."""
    rig._drain()
    send, recv = adapters(rig)
    d = description.decode(data if like is None else like)
    if send_hook is not None:
        send = send_hook(send)
    if recv_hook is not None:
        recv = recv_hook(recv)
    verdict, rows, _clock, transfer = session.run_on_device(
        send, recv, rig.link.max_payload, data, d.ticks, d.n_columns, d.fs, dead_s=float(rig.parameters["dead_s"])
    )
    return verdict, rows, transfer


def _vector(rig, name: str, arithmetic: str = lawcheck.FLOAT64) -> Check:
    vector = vectors.build(vectors.CASES[name])
    try:
        verdict, rows, _ = _run(rig, vector.data)
    except RigError as exc:
        return Check(f"vector {name}", False, str(exc))
    return judge(name, vector, verdict, rows, arithmetic)


def judge(
    name: str, vector: vectors.Vector, verdict: blocks.Verdict, rows: np.ndarray, arithmetic: str = lawcheck.FLOAT64
) -> Check:
    """Vector ``name``'s check of a device's ``verdict`` and logged ``rows`` (ticks, columns): the
    logged y is the sensor table, the law check passes under ``arithmetic``'s tolerance, the verdict
    is the vector's. Also judges a replay of the vector outside a device (the C core's, in tests)."""
    case = vectors.CASES[name]
    info = load_rig(case.rig).info
    outcome = to_result(case.point, info, case.fs, verdict, rows, {}).outcome
    problems = []
    y = [vector.columns.index(s.name) for s in info.outputs]
    n = min(len(rows), len(vector.rows))
    if not np.array_equal(rows[:n, y], vector.rows[:n, y].astype(np.float32), equal_nan=True):
        problems.append("the logged y is not the sensor table (does the device read SENSOR_TABLE?)")
    law = lawcheck.check(
        case.point, info, rows, outcome, fs=case.fs, duration=case.duration, seed=case.seed,
        rig_safety=vectors.rig_safety(case), measured=vector.rows[:, y], arithmetic=arithmetic,
    )  # fmt: skip
    if not law.ok:
        problems.append(f"law {law.flag}: {law.detail}")
    want = (vector.outcome.status, vector.outcome.monitor or "", len(vector.rows))
    got = (verdict.status, verdict.monitor, verdict.n_samples)
    if got != want:
        problems.append(f"verdict {got}, the vector's {want}")
    margin = f"worst |device − law| {law.worst_ratio:.3g} of the {arithmetic} tolerance" + (
        f" ({law.worst_at})" if law.worst_at else ""
    )
    detail = "; ".join(problems) or f"{n} ticks, {verdict.status}, {margin}"
    return Check(f"vector {name}", not problems, detail)


def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def _broken(data: bytes) -> list[tuple[str, bytes]]:
    """Descriptions a device must refuse, each made from the good ``data``."""
    body = bytearray(data[:-4])
    out = [("bad CRC", data[:-1] + bytes([data[-1] ^ 0x5A]))]
    other = bytearray(body)
    struct.pack_into("<H", other, 4, description.VERSION + 1)
    out.append(("another version", _with_crc(bytes(other))))
    out.append(("bad magic", _with_crc(b"LRDX" + bytes(body[4:]))))
    longer = bytearray(body)
    struct.pack_into("<I", longer, 8, struct.unpack_from("<I", body, 8)[0] + 4)
    out.append(("wrong length", _with_crc(bytes(longer))))
    extra = bytearray(body) + description.RECORD.pack(99, 0, 4) + b"\0\0\0\0"
    struct.pack_into("<I", extra, 8, len(extra) - description.HEADER.size)
    struct.pack_into("<H", extra, 14, struct.unpack_from("<H", body, 14)[0] + 1)
    out.append(("unknown record", _with_crc(bytes(extra))))
    kind_at = description.HEADER.size + description.RECORD.size + description.RUN.size  # KIND follows RUN
    _, _, size = description.RECORD.unpack_from(body, kind_at)
    start = kind_at + description.RECORD.size
    unknown = bytearray(body)
    unknown[start : start + size] = b"?" * size
    out.append(("unknown controller kind", _with_crc(bytes(unknown))))
    counts = bytearray(body)
    at = description.HEADER.size + description.RECORD.size + 33  # RUN's u8 outputs
    counts[at] += 1
    out.append(("wrong channel counts", _with_crc(bytes(counts))))
    return out


def _reject(rig, what: str, data: bytes, good: bytes) -> Check:
    try:
        verdict, _, _ = _run(rig, data, like=good)
    except RigError as exc:
        refused = "refused the run" in str(exc)
        return Check(f"reject {what}", refused, str(exc).split(": ", 1)[-1] if refused else str(exc))
    return Check(f"reject {what}", False, f"the device ran it ({verdict.status}, {verdict.n_samples} ticks)")


def _hello_version(rig) -> Check:
    """The answer is awaited for :data:`VERSION_PATIENCE` × the handshake timeout (at least 3 s): the
    check is about what the device answers, not how fast, and an answer arriving after the check gave
    up would be read as an error of the next check (seen under QEMU on a loaded 2-core machine)."""
    rig._drain()
    rig.link.send(m.pack(m.Hello(PROTOCOL_VERSION + 1)))
    patience = max(VERSION_PATIENCE * float(rig.parameters["handshake_timeout_s"]), 3.0)
    deadline, seen = time.monotonic() + patience, []
    while time.monotonic() < deadline:
        frame = rig.link.recv(0.05)
        if frame is not None and frame.kind == Kind.ERROR:
            seen.append(m.unpack(frame).code)
            if seen[-1] == m.ErrorCode.VERSION:
                break
    ok = m.ErrorCode.VERSION in seen
    return Check(
        "hello version", ok, "ERROR VERSION" if ok else f"no ERROR VERSION in {patience:.3g} s (errors seen: {seen})"
    )


def _long_run(case: vectors.Case, ticks: int) -> bytes:
    """A description the host interrupts: the case's sensor table held for ``ticks`` ticks, no run-time limit."""
    rig = load_rig(case.rig)
    safety = {k: v for k, v in vectors.rig_safety(case).items() if k != "max_duration"}
    vector = vectors.build(case)
    table = vector.rows[:, [vector.columns.index(s.name) for s in rig.info.outputs]]
    data = description.build(
        case.point, rig.info, fs=case.fs, duration=ticks / case.fs, seed=case.seed, rig_safety=safety,
        watchdog_s=WATCHDOG_S, sensor_table=table,
    )  # fmt: skip
    return data


def _interrupted(rig, case: vectors.Case, how: str) -> Check:
    """STOP or SAFE mid-run, or the host silent for 2.5 watchdog periods: the run must end failed
    (the watchdog tried once more on a longer run where the device may have outrun the silence)."""
    name = f"{how} mid-run" if how != "watchdog" else "watchdog"
    try:
        verdict, clock, ended_at, rate = _interrupted_run(rig, _long_run(case, LONG_TICKS), how)
        ticks, again = LONG_TICKS, ""
        for _ in range(2):  # a retry the device outran too (sized at a rate it then beat) once more, at its rate
            if how != "watchdog" or verdict.status != "completed":
                break
            lower = ticks / max(ended_at - clock.get("start", clock["t0"]), 1e-3)  # [ticks/s]
            more, words = _outlasting(rate, lower, ticks)
            if more <= ticks:
                again += words
                break
            ticks, again = more, again + words
            verdict, clock, ended_at, rate = _interrupted_run(rig, _long_run(case, ticks), how)
    except RigError as exc:
        return Check(name, False, str(exc))
    word = "watchdog" if how == "watchdog" else "stop"
    ended = verdict.status == "failed" and word in verdict.message.lower() and verdict.n_samples < ticks
    state = _state(rig)
    problems = []
    if not ended:
        problems.append(
            f"the run ended {verdict.status} after {verdict.n_samples} of {ticks} ticks ({verdict.message!r})"
        )
    if state == m.DeviceState.RUNNING:
        problems.append("the device still reports RUNNING")
    took = ended_at - clock["t0"]
    detail = "; ".join(problems) or f"failed after {verdict.n_samples} ticks: {verdict.message!r} ({took:.1f} s)"
    return Check(name, not problems, detail + again)


def _outlasting(rate: float, lower: float, ran: int = LONG_TICKS) -> tuple[int, str]:
    """The ticks a watchdog run needs to outlast the host's silence, and the words for the check, after a
    run of ``ran`` ticks completed: at the loop's rate its PROGRESS showed (``rate`` [ticks/s]; 0: none
    came), where the ``ran`` ticks outlast it the completed run is conclusive; else 10× that at
    ``lower``, the rate it ticked at least (ticks over the time to its verdict, which includes the
    upload of its results)."""
    span = STOP_AFTER_S + 2.5 * WATCHDOG_S  # the run's first answer → the end of the host's silence [s]
    if rate and rate * span <= ran:
        return ran, f"; at the ~{rate:.0f} ticks/s its PROGRESS showed, they outlasted the {span:g} s of silence"
    ticks = min(2**31, max(ran, math.ceil((rate or 10 * lower) * span)))
    return ticks, f"; it had completed all {ran} ticks first (~{rate or lower:.0f}/s), so again with {ticks}"


def _interrupted_run(rig, data: bytes, how: str) -> tuple[blocks.Verdict, dict[str, float], float, float]:
    """Run ``data``, the host sending STOP or SAFE (``how``) :data:`STOP_AFTER_S` after the device's
    first answer, or silent from then for 2.5 watchdog periods; (verdict, the clock's marks: t0,
    start, sent, when the run ended, and the loop's rate from its PROGRESS [ticks/s], 0: unknown).
    RigError as :func:`_run`."""
    clock: dict[str, float] = {"t0": time.monotonic()}

    def recv_hook(recv: session.Recv) -> session.Recv:
        def wrapped(timeout: float):
            now = time.monotonic()
            start = clock.get("start")
            if how != "watchdog" and start is not None and "sent" not in clock and now - start >= STOP_AFTER_S:
                rig.link.send(m.pack(m.Stop(0) if how == "STOP" else m.Safe(0)))
                clock["sent"] = now
            msg = recv(timeout)
            if msg is not None and msg[0] == session.TO_HOST:
                clock.setdefault("start", time.monotonic())  # the device's first answer: the run starts
            return msg

        return wrapped

    def send_hook(send: session.Send) -> session.Send:
        def wrapped(kind: str, payload: bytes) -> None:
            start = clock.get("start")
            silent = start is not None and STOP_AFTER_S <= time.monotonic() - start < STOP_AFTER_S + 2.5 * WATCHDOG_S
            if how == "watchdog" and silent:
                clock.setdefault("sent", time.monotonic())
                return
            send(kind, payload)

        return wrapped

    verdict, _, transfer = _run(rig, data, send_hook=send_hook, recv_hook=recv_hook)
    return verdict, clock, time.monotonic(), transfer.progress_rate


def _state(rig) -> int | None:
    """The device's state from its STATUS answer to a HEARTBEAT (None: no answer)."""
    rig._drain()
    rig.link.send(m.pack(m.Heartbeat(1)))
    deadline = time.monotonic() + 1.0
    while time.monotonic() < deadline:
        frame = rig.link.recv(0.05)
        if frame is not None and frame.kind == Kind.STATUS:
            return m.unpack(frame).state
    return None


def table(checks: Sequence[Check]) -> str:
    """The pass/fail table ``labrunner conform`` prints."""
    width = max(len(c.name) for c in checks)
    lines = [f"{'PASS' if c.passed else 'FAIL'}  {c.name:<{width}}  {c.detail}" for c in checks]
    failed = sum(not c.passed for c in checks)
    lines.append(f"{len(checks) - failed} of {len(checks)} checks passed" + (f"; {failed} FAILED" if failed else ""))
    return "\n".join(lines)
