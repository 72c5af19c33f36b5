"""The device loop's protocol decisions that involve behaviour (docs/device-loop.md § Protocol
decisions), against the emulated device on a python-can ``virtual`` bus in this process: STATUS
during and after a run, a run ending a host-loop SETUP, PROGRESS cadence, ACCEPT as block 0."""

from __future__ import annotations

import time

import numpy as np
import pytest

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.device import blocks, session
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.faults import LinkFaults
from labrunner.rigs.transports.protocol import Kind
from tests.deviceloop_points import POINTS, assert_same_as_twin
from tests.test_deviceloop_faults import _serve, _virtual
from tests.test_deviceloop_link import rig_file

VALVE_S = 2.0  # s: 8000 ticks the emulated valve computes in ~0.5 s (2026-12-06), its samples sent after the run
#: s: 24 000 ticks. The emulated valve computes ~16 000 ticks/s since its twin got faster (2026-12-06; 7000–8000
#: on 2026-12-05): VALVE_S's 8000 took 0.51 s and once finished before a second PROGRESS, which comes every 0.25 s
PROGRESS_S = 6.0


def _valve_run(rig, duration: float = VALVE_S):
    point, _, fs, _, safety = POINTS["valve-mfc1"]
    return rig.run_on_device([point], fs=fs, duration=duration, seeds=[1], rig_safety=safety)[0]


def test_status_says_running_with_the_ticks_done_during_a_run_and_idle_after(monkeypatch):
    config = _virtual(rig_file("valve-mfc1", "can"))
    emulator = _serve(config)
    try:
        rig = load_rig(config_from_dict(config))
        seen = []
        status = rig._status
        monkeypatch.setattr(rig, "_status", lambda msg: seen.append((msg.state, msg.seq)) or status(msg))
        with rig:
            result = _valve_run(rig)
            rig.ping()
    finally:
        emulator.stop()
    assert result.outcome.status == "completed"
    during = [(state, seq) for state, seq in seen[:-1] if state == m.DeviceState.RUNNING]
    assert during and all(0 <= seq < 2**16 for _, seq in during)
    assert max(seq for _, seq in during) > 0  # the ticks done, as they grow
    assert seen[-1][0] == m.DeviceState.IDLE  # after the verdict: idle, the safe input held


def test_a_device_loop_run_ends_a_host_loop_setup_and_its_watchdog():
    """SETUP of a host-loop run (watchdog 0.5 s), then a device-loop run: the host loop's clock
    stops and its watchdog never fires (no ERROR WATCHDOG, which would fail the run on the host)."""
    config = _virtual(rig_file("motor-mfc1", "can"))
    emulator = _serve(config)
    try:
        rig = load_rig(config_from_dict(config))
        with rig:
            rig.handshake()
            for frame in m.setup_frames(200.0, 0.5, 3):
                rig.link.send(frame)
            deadline = time.monotonic() + 3.0  # a loaded machine
            while not emulator.ticking and time.monotonic() < deadline:
                time.sleep(0.005)
            assert emulator.ticking and emulator.state == m.DeviceState.RUNNING
            point, _, fs, duration, safety = POINTS["motor-mfc1"]
            [result] = rig.run_on_device([point], fs=fs, duration=duration, seeds=[11], rig_safety=safety)
            assert not emulator.ticking  # no more host-loop ticks
            received = rig.link.counters.received
            time.sleep(1.2)  # over two host-loop watchdog periods without a frame from the host
            assert rig.link.counters.received == received  # no measurement, no ERROR WATCHDOG
            rig.ping()
    finally:
        emulator.stop()
    assert emulator.last_error == m.ErrorCode.NONE
    assert rig.host.device_errors == 0 and rig.device.state == m.DeviceState.IDLE
    assert_same_as_twin(result, "motor-mfc1", 11)


def test_progress_comes_every_quarter_second_and_accept_is_block_0(monkeypatch):
    config = _virtual(rig_file("valve-mfc1", "can"))
    emulator = _serve(config)
    arrived = []
    take = session._HostRun._take

    def recording(self, block, now):
        arrived.append((now, block.kind, block.seq))
        return take(self, block, now)

    monkeypatch.setattr(session._HostRun, "_take", recording)
    try:
        rig = load_rig(config_from_dict(config))
        with rig:
            result = _valve_run(rig, PROGRESS_S)
    finally:
        emulator.stop()
    assert result.outcome.status == "completed" and not result.diagnostics["device_loop"]["streamed"]
    assert arrived[0][1:] == (blocks.ACCEPT, 0)
    times = [t for t, kind, _ in arrived if kind in (blocks.ACCEPT, blocks.PROGRESS)]
    assert result.diagnostics["device_loop"]["device_compute_s"] > 0.75, result.diagnostics  # long enough …
    assert len(times) >= 3  # … for PROGRESS to come at least twice
    assert max(b - a for a, b in zip(times, times[1:])) < 0.6  # 0.25 s, and a loaded machine's slack
    assert [seq for _, _, seq in arrived] == list(range(len(arrived)))  # one numbering from ACCEPT to VERDICT
    # the loop's rate as its PROGRESS showed it on the host's clock: that of the free-running emulator's
    # compute time (7060 and 7970 ticks/s against 7360 and 6790 in two tries, 2026-12-05)
    loop = result.diagnostics["device_loop"]
    assert loop["progress_rate"] == pytest.approx(loop["ticks"] / loop["device_compute_s"], rel=0.5), loop


def test_host_loop_tick_numbers_wrap_at_2_16_on_both_ends():
    """Both ends start 5 ticks before the u16 seq wraps: the run goes on through tick 65536 = seq 0
    with every measurement the direct twin's (compared by (expected − received) mod 2¹⁶)."""
    from test_transports import U, direct_run
    from test_transports_faults import serve

    rig, emulator = serve(LinkFaults())
    emulator.rig.reset(
        1, [3], 200.0
    )  # the twin's first set-up loads its modules (~0.5 s here): not within y_0's deadline
    try:
        ys = [rig.reset(1, [3], 200.0)[0, 0]]
        device = emulator.handlers[Kind.INPUT].__self__  # the host-loop service (hostloop_device)
        rig._seq = device.k = 2**16 - 5
        ys += [rig.step(np.array([[v]]))[0, 0] for v in U[:20]]
        seq = rig._seq
    finally:
        rig.close()
        emulator.stop()
    assert seq == 15 and rig.host.stale == 0 and rig.host.lost_ticks == 0
    np.testing.assert_allclose(ys, direct_run(U[:20], 3), rtol=1e-6, atol=1e-6)
