"""Injected link faults: each is detected, counted and never used as data (the host-loop rules).

The host runs the motor twin's inputs against the emulated device; every measurement it returns
must equal the direct twin run's (the reference), whatever the device's link adds or loses.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from test_transports import U, can_config, direct_run, serial_config

from labrunner.errors import RigError
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.emulator import Emulator, device_link, serve_on_pty, twin_for
from labrunner.rigs.transports.faults import LinkFaults
from labrunner.rigs.transports.protocol import Kind


def run_until_failure(rig, u: np.ndarray, seed: int = 3) -> tuple[np.ndarray, RigError | None]:
    """The measurements the host got, and the RigError that ended the run early (or None)."""
    ys = []
    try:
        ys.append(rig.reset(1, [seed], 200.0)[0, 0])
        for v in u:
            ys.append(rig.step(np.array([[v]]))[0, 0])
    except RigError as exc:
        return np.array(ys), exc
    return np.array(ys), None


def serve(faults: LinkFaults, interface: str = "virtual", paced: bool = False, **parameters):
    parameters.setdefault("watchdog_periods", 200)  # 1 s at 200 Hz: these tests are about the link, not the watchdog
    config = can_config(interface, **parameters)
    emulator = Emulator(twin_for(config), device_link(config), paced=paced, faults=faults).start()
    return load_rig(config), emulator


@pytest.mark.parametrize(
    "fault, counter",
    [
        ({"duplicate": 0.5}, lambda d: d["host"]["duplicate"] + d["host"]["stale"]),
        ({"stale": 0.3}, lambda d: d["host"]["stale"]),
        ({"spoof": 0.3}, lambda d: d["link"]["spoofed"]),
        ({"garbage": 0.3}, lambda d: d["link"]["malformed"]),
        ({"error_frame": 0.3}, lambda d: d["link"]["error_frames"]),
    ],
)
def test_extra_frames_are_counted_and_ignored(fault, counter):
    rig, emulator = serve(LinkFaults(seed=1, **fault))
    try:
        ys, failure = run_until_failure(rig, U)
        diagnostics = rig.diagnostics()
    finally:
        rig.close()
        emulator.stop()
    assert failure is None
    np.testing.assert_allclose(ys, direct_run(U, 3), rtol=1e-6, atol=1e-6)  # the data is the twin's, untouched
    assert counter(diagnostics) > 0


def test_garbage_on_a_serial_line_is_counted_and_the_line_resyncs():
    twin = twin_for(serial_config("unused"))
    name, emulator = serve_on_pty(twin, paced=False, faults=LinkFaults(garbage=0.5, seed=2))
    try:
        rig = load_rig(serial_config(name))
        ys, failure = run_until_failure(rig, U)
        link = rig.diagnostics()["link"]
        rig.close()
    finally:
        emulator.stop(close_link=False)
    assert failure is None
    np.testing.assert_allclose(ys, direct_run(U, 3), rtol=1e-6, atol=1e-6)
    assert link["garbage_bytes"] > 0 and link["crc_errors"] + link["malformed"] > 0


def test_dropped_frames_fail_the_run_and_no_value_is_made_up():
    rig, emulator = serve(LinkFaults(drop=0.2, seed=4), timeout_s=0.05)
    try:
        ys, failure = run_until_failure(rig, U)
        host = rig.diagnostics()["host"]
    finally:
        rig.close()
        emulator.stop()
    assert failure is not None and ("incomplete" in str(failure) or "no complete measurement" in str(failure))
    np.testing.assert_allclose(ys, direct_run(U, 3)[: len(ys)], rtol=1e-6, atol=1e-6)
    assert rig.is_safe.all() and len(ys) < len(U) + 1
    assert host["lost_ticks"] + ("no complete" in str(failure)) >= 1


class LoseOneChannel:
    """Wraps the device link: the first output channel of tick ``tick`` never leaves the device."""

    def __init__(self, inner, tick: int) -> None:
        self.inner, self.tick = inner, tick

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def send(self, frame) -> None:
        if frame.kind == Kind.MEASUREMENT:
            msg = m.unpack(frame)
            if msg.seq == self.tick and msg.channel == 0:
                return
        self.inner.send(frame)


def test_a_tick_with_a_lost_channel_is_never_committed():
    """The plate has four outputs: channel 0 of tick 5 is lost, channels 1..3 and the trailer arrive."""
    config = can_config("virtual", device="plate", watchdog_periods=32000)  # 1 s: the test is not paced
    emulator = Emulator(twin_for(config), LoseOneChannel(device_link(config), 5), paced=False).start()
    rig = load_rig(config)
    try:
        rig.reset(1, [0], 32000.0)
        for _ in range(4):
            rig.step(np.full((1, 4), 2.0))
        with pytest.raises(RigError, match=r"tick 5 incomplete: channels \[0\] lost"):
            rig.step(np.full((1, 4), 2.0))
        assert rig.diagnostics()["host"]["lost_ticks"] == 1 and rig.is_safe.all()
    finally:
        rig.close()
        emulator.stop()


def test_a_dying_device_is_detected_within_the_timeout_and_the_rig_goes_safe():
    rig, emulator = serve(LinkFaults(die_after_s=0.3), paced=True, timeout_s=0.05, max_late_ticks=10**6)
    try:
        rig.reset(1, [0], 200.0)
        t_dead = None
        with pytest.raises(RigError, match="no complete measurement"):
            for _ in range(400):
                t = time.monotonic()
                rig.step(np.array([[1.0]]))
                t_dead = t
        assert time.monotonic() - t_dead < 0.05 + 2 / 200.0 + 0.2 and rig.is_safe.all()
    finally:
        rig.close()
        emulator.stop()


def test_a_slow_link_makes_late_ticks_that_fail_the_run():
    """Every device frame 20 ms late at 200 Hz: each input misses its deadline; the device holds
    the last input and flags the ticks LATE, the host counts them and stops after max_late_ticks."""
    rig, emulator = serve(LinkFaults(delay_ms=20.0), paced=True, timeout_s=0.2, max_late_ticks=3)
    try:
        ys, failure = run_until_failure(rig, U)
        host = rig.diagnostics()["host"]
    finally:
        rig.close()
        emulator.stop()
    assert failure is not None and "late ticks in a row" in str(failure)
    assert host["late_ticks"] == 4 and len(host["late_tick_indices"]) == 4
    assert emulator.late >= 4 and rig.is_safe.all()


def test_device_counts_rejected_frames_and_reports_them_in_status():
    rig, emulator = serve(LinkFaults())
    try:
        rig.reset(1, [0], 200.0)
        rig.step(np.array([[1.0]]))
        rig.link.send(m.pack(m.Input(0, 0, m.FLAG_COMMIT, 9.0)))  # for tick 0 again: too late, dropped
        rig.ping()
        assert rig.device.rejected >= 1 and emulator.rejected >= 1
        y = rig.step(np.array([[1.0]]))  # the run goes on, the stale input was never applied
        assert emulator.host_loop.applied[0, 0] == 1.0 and np.isfinite(y).all()
    finally:
        rig.close()
        emulator.stop()


def test_a_long_burst_echoed_back_counts_as_echoes_not_spoofed_frames():
    """udp_multicast loops a node's own frames back, here after a burst of 1000 bulk frames (a
    device-loop upload): every echo is recognised as this end's own frame; a device-kind frame
    with the host's node id that the host never sent counts as spoofed."""
    from labrunner.rigs.transports.link import Link
    from labrunner.rigs.transports.protocol import End, Frame, Kind

    class Loopback(Link):
        def __init__(self) -> None:
            super().__init__(1, End.DEVICE)
            self.wire: list[tuple[Kind, bytes]] = []

        max_payload = 8

        def _send(self, kind: Kind, payload: bytes) -> None:
            self.wire.append((kind, payload))

        def recv(self, timeout: float) -> Frame | None:
            return None

        def close(self) -> None:
            pass

    link = Loopback()
    for i in range(1000):
        link.send(Frame(Kind.BULK_TO_HOST, i.to_bytes(4, "little")))
    for kind, payload in link.wire:
        assert link._accept(1, kind, End.DEVICE, payload) is None
    assert link._accept(1, Kind.BULK_TO_HOST, End.DEVICE, b"\xff" * 8) is None
    assert (link.counters.echoes, link.counters.spoofed) == (1000, 1)
