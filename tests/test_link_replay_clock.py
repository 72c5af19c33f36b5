"""Issue 36: a device that replays old frames, and a device whose clock is reset to 0, are link
faults: the run fails with the reason (the rig safe), never recorded as a property of the gains
(an |du/dt| abort on replayed values) or as time (a +4295 s wrap). The emulator injects both
(``LinkFaults.replay``, ``clock_reset_tick``; ``labrunner emulate --replay --clock-reset-tick K``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_campaign_support import campaign_text, ledger_rows, write
from test_transports import U, direct_run
from test_transports_faults import run_until_failure, serve
from test_transports_hostloop import can_rig_file, emulate, stop

from labrunner.cli import main
from labrunner.errors import RigError
from labrunner.rigs.transports.faults import LinkFaults


def test_frames_replayed_from_the_previous_run_fail_the_run_as_a_link_fault():
    rig, emulator = serve(LinkFaults(replay=True))
    try:
        first, failure = run_until_failure(rig, U, seed=3)  # nothing recorded yet to replay
        assert failure is None
        np.testing.assert_allclose(first, direct_run(U, 3), rtol=1e-6, atol=1e-6)
        second, failure = run_until_failure(rig, -U, seed=3)  # its frames follow the first run's
        safe = bool(rig.is_safe.all())
    finally:
        rig.close()
        emulator.stop()
    assert isinstance(failure, RigError) and "the device replays old frames" in str(failure), failure
    assert "link fault" in str(failure) and safe
    assert emulator.link.injected["replay"] > 0
    np.testing.assert_allclose(second, direct_run(-U, 3)[: len(second)], rtol=1e-6, atol=1e-6)  # no old value used


def test_a_device_clock_reset_to_0_fails_the_run_instead_of_wrapping():
    rig, emulator = serve(LinkFaults(clock_reset_tick=20))
    try:
        ys, failure = run_until_failure(rig, U)
        clock = rig.device_clock()
        safe = bool(rig.is_safe.all())
    finally:
        rig.close()
        emulator.stop()
    assert isinstance(failure, RigError) and "link fault: the device clock went from" in str(failure), failure
    assert "at tick 20" in str(failure) and safe and len(ys) == 20
    assert clock.max() < 1.0  # 20 ticks at 200 Hz: no +4295 s step was ever taken as time


def test_the_u32_clock_wrapping_is_still_time_passing():
    rig, emulator = serve(LinkFaults())
    try:
        rig.reset(1, [3], 200.0)
        rig._clock[-1] = (2**32 - 2_000) * 1e-6  # as if 71.6 min into the run: the next stamp wraps
        from labrunner.rigs.transports import messages as m

        step = rig._clock_step(m.TickEnd(1, m.TICK_CHANNEL, 0, 3_000), 1)
    finally:
        rig.close()
        emulator.stop()
    assert step == pytest.approx(5_000e-6)


@pytest.mark.parametrize("fault", [("--replay",), ("--clock-reset-tick", "40")])
def test_a_campaign_records_the_link_fault_as_failed_with_its_reason(project, fault):
    path = can_rig_file(project / "rigs" / "motor-can.toml", watchdog_periods=10, realtime=True)
    campaign = write(
        project / "c.toml",
        campaign_text(
            name="can", rig="rigs/motor-can.toml", duration=0.5, grid='"controller.k_p" = { values = [10.0, 20.0] }'
        ),
    )
    device = emulate(path, *fault)
    try:
        assert main(["run", str(campaign), "--workers", "1"]) in (0, 1)  # a failed point: going on or stopped
    finally:
        stop(device)
    rows = ledger_rows(project / "data" / "can")
    failed = [json.loads(r["outcome_json"]) for r in rows if r["state"] == "failed"]
    assert failed and all("link fault" in f["message"] for f in failed), failed  # replay: the second run; reset: each
    assert not [r for r in rows if r["state"] == "aborted"]  # never a property of the gains


def _samples(first: int, n: int, t_us: int):
    from labrunner.rigs.device import blocks
    from labrunner.rigs.transports.bulk import Block

    return Block(first, 0, blocks.SAMPLES, 0, blocks.encode_samples(first, np.full((n, 1), float(first)), t_us))


def test_device_loop_samples_whose_clock_goes_back_or_that_replay_are_link_faults():
    from labrunner.rigs.device.session import _HostRun

    run = _HostRun(lambda *a: None, lambda t: None, 64, 10, 1, 100.0, 1.0)
    assert run._take(_samples(0, 4, 0), 0.0) is None
    assert run._take(_samples(4, 2, 40_000), 0.0) is None  # 4 ticks at 100 Hz later: on time
    np.testing.assert_allclose(run.clock[:6], np.arange(6) / 100.0)
    with pytest.raises(RigError, match=r"link fault: the device clock went from 0\.050000 s to 0\.000000 s at tick 6"):
        run._take(_samples(6, 2, 0), 0.0)  # the device's clock reset to 0
    with pytest.raises(RigError, match=r"link fault: SAMPLES block for ticks 0\.\.3 after 6 ticks"):
        run._take(_samples(0, 4, 0), 0.0)  # an old block replayed
