"""A remote rig's device loop: the host side of ``loop = "device"`` over the rig's Link v1.

:func:`run_on_device` is what :meth:`RemoteRig.run_on_device` does: handshake (the device must
announce DEVICE_LOOP), then per point one description, its results and a RunResult whose
``diagnostics`` hold the link's counters of that run, the device's timing and the transfer's
figures. An ERROR frame, a device that sends no bulk frame for 1 s (dead or hung) or a transfer that gets no
block through for 10 s raise :class:`~labrunner.errors.RigError` after a SAFE to the device, with ``results``:
the runs before and the failed run's partial log (the campaign worker then checks the device with a
fresh handshake, :meth:`~labrunner.rigs.transports.remote.RemoteRig.recover`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

from labrunner.engine import RunResult
from labrunner.errors import RigError
from labrunner.rigs.device import host, lawcheck, session
from labrunner.rigs.transports import linkload, messages as m
from labrunner.rigs.transports.protocol import Frame, Kind

DEVICE_WATCHDOG_MIN_S = 1.0  #: shortest host-silence watchdog of a device-loop run [s]
_OUT = {session.TO_DEVICE: Kind.BULK_TO_DEVICE, session.ACK: Kind.BULK_ACK}
_IN = {Kind.BULK_TO_HOST: session.TO_HOST, Kind.BULK_ACK: session.ACK}


def watchdog_s(parameters: Mapping[str, Any], fs: float) -> float:
    """The device loop's host-silence watchdog: the rig file's periods, at least 1 s (the host
    only sends ACKs and heartbeats while the device runs)."""
    return max(float(parameters["watchdog_periods"]) / fs, DEVICE_WATCHDOG_MIN_S)


def adapters(rig) -> tuple[session.Send, session.Recv]:
    """The bulk session's ``send`` and ``recv`` over ``rig``'s link: bulk frames both ways, a
    HEARTBEAT for the session's keep-alive; an ERROR frame raises RigError, a STATUS is kept."""
    link = rig.link
    beats = [0]

    def send(kind: str, payload: bytes) -> None:
        if kind == session.HEARTBEAT:
            beats[0] += 1
            frame = m.pack(m.Heartbeat(beats[0] % 2**16))
        else:
            frame = Frame(_OUT[kind], payload)
        try:
            link.send(frame)
        except RigError as exc:
            rig._fail(str(exc))

    def recv(timeout: float) -> tuple[str | None, bytes] | None:
        try:
            frame = link.recv(timeout)
        except RigError as exc:
            rig._fail(str(exc))
        if frame is None:
            return None
        if frame.kind in _IN:
            return _IN[frame.kind], frame.payload
        if frame.kind == Kind.ERROR:
            rig._device_error(m.unpack(frame))
        if frame.kind == Kind.STATUS:
            rig._status(m.unpack(frame))
        return None, frame.payload

    return send, recv


def run_on_device(
    rig,
    points: Sequence[Mapping[str, object]],
    *,
    fs: float,
    duration: float,
    seeds: Sequence[int],
    rig_safety: Mapping[str, object] | None = None,
) -> list[RunResult]:
    """Run ``points`` one after the other on ``rig``'s device (a RemoteRig with ``loop = "device"``)."""
    if rig.identity is None:
        rig.handshake()
    if not rig.identity.capabilities & m.Capability.DEVICE_LOOP:
        rig._fail("the device does not run a device loop (capabilities lack DEVICE_LOOP)")
    link = rig.link
    send, recv = adapters(rig)
    spec = linkload.from_rig(rig.KIND, rig.parameters)
    wd = watchdog_s(rig.parameters, fs)
    arithmetic = lawcheck.arithmetic_of(rig.identity.capabilities)
    results: list[RunResult] = []
    for point, seed in zip(points, seeds):
        rig._drain()
        before = replace(link.counters)

        def wrapped(result: RunResult) -> RunResult:
            now, then = link.counters.as_dict(), before.as_dict()
            result.diagnostics = {
                "loop": "device",
                "link": {k: now[k] - then[k] for k in now},
                "firmware_id": rig.identity.firmware_id,
                "device_loop": result.diagnostics,
                "law_check": result.diagnostics.get("law_check"),  # docs/control-laws.md § The host's check
            }
            return result

        try:
            [result] = host.run(
                send,
                recv,
                link.max_payload,
                [point],
                rig.info,
                fs=fs,
                duration=duration,
                seeds=[seed],
                rig_safety=rig_safety,
                watchdog_s=wd,
                link=spec,
                reference_table=bool(rig.parameters["reference_table"]),
                arithmetic=arithmetic,
                dead_s=float(rig.parameters["dead_s"]),
            )
        except RigError as exc:  # the run failed on the host: SAFE ends it on the device (best effort)
            with contextlib.suppress(RigError):
                link.send(m.pack(m.Safe(0)))
            exc.results = [*results, *(wrapped(r) for r in getattr(exc, "results", ()))]
            raise
        results.append(wrapped(result))
    return results
