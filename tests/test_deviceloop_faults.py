"""Faults on a real rig fail one point, fast, with the reason and the log up to the failure; the
campaign goes on once the device answers a fresh handshake in its safe state, and stops after the
rig file's ``max_consecutive_failures`` points in a row (docs/device-loop.md § Faults).

The emulated device runs in this process on a python-can ``virtual`` bus (and, for
``labrunner emulate --die-after``, in its own process over ``udp_multicast``)."""

from __future__ import annotations

import json
import threading
import time
import uuid
from dataclasses import replace

import numpy as np
import pytest
from test_campaign_support import campaign_text, ledger_rows, write

from labrunner.cli import main
from labrunner.errors import RigError
from labrunner.logs import read_run
from labrunner.rigs.config import config_from_dict
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.emulator import Emulator, device_link, twin_for
from labrunner.rigs.transports.faults import LinkFaults
from tests.deviceloop_points import MOTOR_SAFETY, POINTS, assert_same_as_twin
from tests.test_deviceloop_link import emulator_process, rig_file, rig_toml

LONG = 40.0  # s: a motor run the emulated device computes for about a second, streaming its samples
SAFETY = {**MOTOR_SAFETY, "max_duration": 100.0}


def _virtual(config: dict) -> dict:
    """``config`` (a rig file) on a fresh python-can virtual bus of this process."""
    parameters = {**config["parameters"], "interface": "virtual", "channel": f"lr-{uuid.uuid4().hex}", "port": 0}
    return {**config, "parameters": parameters}


def _serve(config: dict, faults: LinkFaults | None = None) -> Emulator:
    return Emulator(twin_for(config_from_dict(config)), device_link(config_from_dict(config)), faults=faults).start()


def _long_run(rig):
    point, _, fs, _, _ = POINTS["motor-mfc1"]
    return rig.run_on_device([point], fs=fs, duration=LONG, seeds=[1], rig_safety=SAFETY)


def test_a_dead_device_fails_the_run_within_a_second_keeps_its_samples_and_is_not_taken_back():
    config = _virtual(rig_file("motor-mfc1", "can"))
    emulator = _serve(config, LinkFaults(die_after_s=1.0))  # its first samples come after ~0.5 s (loaded machine)
    try:
        rig = load_rig(config_from_dict(config))
        with rig:
            t0 = time.monotonic()
            with pytest.raises(RigError, match="no frame from the device for 1 s during the run") as caught:
                _long_run(rig)
            noticed = time.monotonic() - t0
            with pytest.raises(RigError, match="does not answer a fresh handshake.*may not be in its safe state"):
                rig.recover()
    finally:
        emulator.stop()
    assert noticed < 1.0 + 1.0 + 0.8  # the death, one DEAD_S, scheduling slack
    [partial] = caught.value.results
    assert partial.outcome.status == "failed" and "dead or hung" in partial.outcome.message
    assert 0 < partial.n_samples < LONG * 200  # the streamed samples up to the death are kept
    assert partial.diagnostics["loop"] == "device" and partial.diagnostics["device_loop"]["columns"] == 6
    law = partial.diagnostics["law_check"]  # checked up to its last sample, never null (docs/control-laws.md)
    assert law["flag"] == "ok" and law["arithmetic"] == "float64", law


def test_a_device_that_was_silent_for_a_while_answers_a_fresh_handshake_and_runs_the_next_point():
    """Everything the device sends is lost for a while (a hung link, a device stalled): the host
    gives up on that run after DEAD_S and SAFE; the device ends its run, answers the handshake in
    its safe state, and the next run gives the twin's result."""
    config = _virtual(rig_file("motor-mfc1", "can"))
    emulator = _serve(config, LinkFaults(seed=1, drop=1e-12))  # a FaultyLink whose faults the test switches
    link = emulator.link

    def fall_silent():
        time.sleep(0.2)
        link.faults = replace(link.faults, drop=1.0)

    try:
        rig = load_rig(config_from_dict(config))
        with rig:
            threading.Thread(target=fall_silent, daemon=True).start()
            with pytest.raises(RigError, match="no frame from the device") as caught:
                _long_run(rig)
            link.faults = replace(link.faults, drop=0.0)
            rig.recover()
            assert rig.device.state in (m.DeviceState.SAFE, m.DeviceState.IDLE)
            point, _, fs, duration, safety = POINTS["motor-mfc1"]
            [result] = rig.run_on_device([point], fs=fs, duration=duration, seeds=[11], rig_safety=safety)
    finally:
        emulator.stop()
    partial = caught.value.results[0]
    assert partial.outcome.status == "failed" and len(partial.device_clock) == partial.n_samples
    assert_same_as_twin(result, "motor-mfc1", 11)
    # the emulated device's clock is virtual: tick k at k/f_s exactly, from each SAMPLES block's time
    np.testing.assert_allclose(result.device_clock, np.arange(result.n_samples) / 200.0, rtol=0, atol=1e-9)


def test_recover_refuses_a_device_that_reported_its_own_protection():
    config = _virtual(rig_file("motor-mfc1", "can"))
    emulator = _serve(config)
    try:
        rig = load_rig(config_from_dict(config))
        with rig:
            rig.handshake()
            emulator.inject_fault(m.ErrorCode.DEVICE_FAULT)
            with pytest.raises(RigError, match="DEVICE_FAULT"):
                rig.ping()
            with pytest.raises(RigError, match="reported DEVICE_FAULT"):
                rig.recover()
    finally:
        emulator.stop()


@pytest.mark.slow
def test_emulate_die_after_acts_in_the_device_loop():
    with emulator_process(rig_file("motor-mfc1", "can"), ("--die-after", "1.0")) as config:
        rig = load_rig(config_from_dict(config))
        with rig:
            t0 = time.monotonic()
            with pytest.raises(RigError, match="no frame from the device for 1 s") as caught:
                _long_run(rig)
            assert time.monotonic() - t0 < 1.0 + 1.0 + 0.8
    assert 0 < caught.value.results[0].n_samples < LONG * 200


# -- the campaign: one point fails, the campaign goes on, N in a row stop it ---------------------------


def _host_loop_rig(project, limit: int) -> tuple[dict, str]:
    """A host-loop motor rig file on a virtual bus. Served with ``drop=0.05`` its device loses a frame
    within a run's first ticks (every run fails; a handshake, asking up to three times, gets through);
    with ``delay_ms=6`` at 200 Hz every input misses its tick (11 late ticks in a row fail a run)."""
    config = _virtual(rig_file("motor-mfc1", "can"))
    config["parameters"].update(loop="host", timeout_s=0.05, watchdog_periods=200, max_consecutive_failures=limit)
    config["parameters"].pop("data_bitrate"), config["parameters"].pop("fd")
    path = write(project / "rigs" / "flaky.toml", rig_toml(config))
    return config, str(path)


@pytest.mark.parametrize(
    "faults, limit, failed, reason",
    [
        (LinkFaults(drop=0.05, seed=4), 2, 2, ""),  # a lost frame: "tick k incomplete", "no complete measurement", ...
        (LinkFaults(drop=0.05, seed=4), 10, 4, ""),
        (LinkFaults(delay_ms=6.0), 2, 2, "late ticks in a row at 200 Hz"),  # late frames: inputs miss their ticks
    ],
)
def test_a_lost_or_late_frame_fails_one_point_with_its_log_and_the_campaign_goes_on_until_n_in_a_row(
    project, capsys, faults, limit, failed, reason
):
    config, _ = _host_loop_rig(project, limit)
    grid = '"controller.k_p" = { values = [10.0, 20.0, 30.0, 40.0] }'
    path = write(project / "flaky.toml", campaign_text(name="flaky", rig="rigs/flaky.toml", grid=grid))
    emulator = _serve(config, faults)
    try:
        code = main(["run", str(path)])
    finally:
        emulator.stop()
    err = capsys.readouterr().err
    rows = ledger_rows(project / "data" / "flaky")
    states = [r["state"] for r in rows]
    assert states.count("failed") == failed and states.count("planned") == 4 - failed, err
    for row in rows[:failed]:
        message = json.loads(row["outcome_json"])["message"]
        assert message.startswith("RigError: rig 'dcmotor-can': ") and reason in message
        log = read_run(str(project / "data" / "flaky" / row["log_path"]))  # the log up to the failure
        assert log.outcome["status"] == "failed" and len(log.frame) < 400
    if failed < 4:
        assert code == 1 and f"{limit} points in a row failed on the rig" in err and "max_consecutive_failures" in err
    else:
        assert code == 0 and "going on" in err


def test_a_dead_host_loop_device_stops_the_campaign_saying_the_rig_may_not_be_safe(project, capsys):
    config, _ = _host_loop_rig(project, 5)
    path = write(project / "dead.toml", campaign_text(name="dead", rig="rigs/flaky.toml"))
    emulator = _serve(config, LinkFaults(die_after_s=0.3))
    try:
        assert main(["run", str(path)]) == 1
    finally:
        emulator.stop()
    err = capsys.readouterr().err
    assert "does not answer a fresh handshake" in err and "may not be in its safe state" in err
    states = [r["state"] for r in ledger_rows(project / "data" / "dead")]
    assert states.count("failed") == 1 and states.count("planned") == 8


# -- timing a user sees: late ticks and overruns in status, analyse, metrics.csv and the report ---------


def test_late_ticks_and_overruns_show_in_status_analyse_metrics_csv_and_the_report(project, capsys):
    """A host loop whose device answers 6 ms late at 200 Hz (5 ms periods): its inputs miss their
    deadlines, the device holds them and flags the ticks LATE. Every view shows the counts the runs'
    own diagnostics records hold (read from the MCAPs: the reference)."""
    import pandas as pd

    config = _virtual(rig_file("motor-mfc1", "can"))
    config["parameters"].update(loop="host", timeout_s=0.1, watchdog_periods=200, max_late_ticks=1_000_000)
    config["parameters"].pop("data_bitrate"), config["parameters"].pop("fd")
    write(project / "rigs" / "slow.toml", rig_toml(config))
    grid = '"controller.k_p" = { values = [10.0, 20.0] }'
    path = write(project / "slow.toml", campaign_text(name="slow", rig="rigs/slow.toml", grid=grid, duration=1.0))
    emulator = Emulator(
        twin_for(config_from_dict(config)), device_link(config_from_dict(config)), faults=LinkFaults(delay_ms=6.0)
    ).start()
    try:
        assert main(["run", str(path)]) == 0
    finally:
        emulator.stop()
    directory = project / "data" / "slow"
    rows = ledger_rows(directory)
    runs = [read_run(str(directory / r["log_path"])) for r in rows]
    logs = {r["id"]: log.metadata["diagnostics"]["host"] for r, log in zip(rows, runs)}
    for log in runs:  # the device's own clock, second channel: its trailers' timestamps, from tick 0
        t = log.frame["t_device"].to_numpy()
        assert log.channels["t_device"] == {"role": "signal", "unit": "s"} and t[0] == 0.0
        assert np.all(np.diff(t) > 0) and t[-1] >= (len(t) - 1) / 200.0 - 1e-3  # paced; an overrun slips it later
    late = {k: d["late_ticks"] for k, d in logs.items()}
    over = {k: d["overruns"] for k, d in logs.items()}
    assert all(n > 0 for n in late.values())
    capsys.readouterr()
    assert main(["status", str(directory), "--json"]) == 0
    timing = json.loads(capsys.readouterr().out)["timing"]
    assert timing == {
        "runs": 2,
        "late_ticks": sum(late.values()),
        "overruns": sum(over.values()),
        "runs_with_late_ticks": 2,
        "runs_with_overruns": sum(n > 0 for n in over.values()),
    }
    assert main(["status", str(directory)]) == 0
    assert f"timing on the rig: {sum(late.values())} late tick(s) in 2 run(s)" in capsys.readouterr().out
    assert main(["analyse", str(directory)]) == 0
    out = capsys.readouterr().out
    assert f"timing on the rig: {sum(late.values())} late tick(s) in 2 run(s)" in out
    table = pd.read_csv(directory / "report" / "metrics.csv")
    assert dict(zip(table["id"], table["late_ticks"])) == late and dict(zip(table["id"], table["overruns"])) == over
    report = (directory / "report" / "index.html").read_text()
    assert f"{sum(late.values())} late tick(s) in 2 run(s)" in report


def test_a_device_of_another_kind_is_reported_as_such_not_as_dead():
    """It answered: 'dead or hung, may not be in its safe state' would send the user to the wrong place."""
    motor = _virtual(rig_file("motor-mfc1", "can"))
    valve = {**rig_file("valve-mfc1", "can"), "parameters": {**motor["parameters"], "device": "valve"}}
    emulator = _serve(valve)
    try:
        rig = load_rig(config_from_dict(motor))
        with rig:
            with pytest.raises(RigError, match=r"device kind 2 \(expected 1\)"):
                rig.handshake()
            with pytest.raises(RigError) as caught:
                rig.recover()
    finally:
        emulator.stop()
    message = str(caught.value)
    assert "answers the handshake but is not the rig file's device" in message
    assert "dead or hung" not in message and "may not be in its safe state" not in message
