"""The reference-law check of device-loop runs (docs/control-laws.md, "The host's check"): a
device that runs the law passes at float32 logging, one that runs a slightly wrong law, a wrong
sample or a wrong verdict is caught at its first diverging tick — in-process here, and through
``labrunner run`` against ``labrunner emulate --fault-law`` with the flag in ``status``,
``analyse`` and metrics.csv."""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_campaign_support import cli

from labrunner import OUTCOME_KEYS
from labrunner.logs import read_metadata
from labrunner.rigs.device import description, executor, lawcheck
from labrunner.rigs.device.host import to_result
from labrunner.rigs.registry import load_rig
from tests.deviceloop_points import POINTS
from tests.test_deviceloop_link import ROOT, emulator_process, rig_file, rig_toml

MFC_POINTS = ("motor-mfc1", "motor-mfc2", "motor-aborted", "valve-mfc1", "plate-mfc")


def _device(name: str, law_fault=None, seed: int = 3):
    """(rows, outcome) of the emulated device's run of ``name`` (its reference executor). The
    fault-free run is computed once per point and seed (:func:`_right`)."""
    return _execute(name, law_fault, seed) if law_fault is not None else _right(name, seed)


@functools.cache
def _right(name: str, seed: int):
    """The fault-free run: a pure computation that several tests read (the plain check, the
    faulty run's reference, the altered copies); its rows are read-only, a test alters a copy."""
    rows, outcome = _execute(name, None, seed)
    rows.flags.writeable = False
    return rows, outcome  # Outcome is a frozen dataclass


def _execute(name: str, law_fault, seed: int):
    point, rig_name, fs, duration, safety = POINTS[name]
    rig = load_rig(rig_name)
    data = description.build(point, rig.info, fs=fs, duration=duration, seed=seed, rig_safety=safety)
    run = executor.execute(data, rig, law_fault=law_fault)
    return run.columns, to_result(point, rig.info, fs, run.verdict, run.columns, {}).outcome


def _check(name: str, rows, outcome, seed: int = 3) -> lawcheck.LawCheck:
    point, rig_name, fs, duration, safety = POINTS[name]
    info = load_rig(rig_name).info
    return lawcheck.check(point, info, rows, outcome, fs=fs, duration=duration, seed=seed, rig_safety=safety)


@pytest.mark.parametrize("name", sorted(POINTS))
def test_a_device_running_the_law_passes_with_margin(name):
    rows, outcome = _device(name)
    law = _check(name, rows, outcome)
    assert law.flag == "ok", law.detail
    assert law.worst_ratio < 0.5  # float32 logging uses at most half the tolerance


@pytest.mark.parametrize("name", MFC_POINTS)
def test_a_device_with_gamma_two_percent_off_is_caught_on_its_first_run(name):
    rows, outcome = _device(name, law_fault={"gamma": 1.02})
    law = _check(name, rows, outcome)
    assert law.flag.startswith("diverged@tick ") and law.tick is not None
    assert law.flag == f"diverged@tick {law.tick}"
    right, _ = _device(name)
    acting = int(np.flatnonzero(right[:, 0] != right[0, 0])[0]) if (right[:, 0] != right[0, 0]).any() else 0
    assert law.tick <= acting + 2  # within two ticks of the law's first change of the input (γ scales it)
    assert law.column in ("u", "i", "i1", "i2", "i3", "i4") or law.column.startswith(("f_hat", "e_hat", "de_hat"))


def test_one_wrong_input_sample_is_caught_at_its_tick():
    rows, outcome = _device("motor-mfc1")
    bad = rows.copy()
    bad[100, 0] = np.float32(bad[100, 0] * 1.0005)  # the device's u at tick 100, 0.05 % off
    law = _check("motor-mfc1", bad, outcome)
    assert (law.flag, law.tick, law.column) == ("diverged@tick 100", 100, "u")
    assert law.device == pytest.approx(float(bad[100, 0])) and law.expected == pytest.approx(float(rows[100, 0]))


def test_a_wrong_reference_is_caught():
    rows, outcome = _device("motor-mfc1")
    bad = rows.copy()
    bad[150:, 3] += np.float32(1e-3)  # ref_omega: column 3 of u, theta, omega, ref_omega, ...
    law = _check("motor-mfc1", bad, outcome)
    assert law.tick == 150 and law.column in ("ref_omega", "u", "f_hat_omega", "e_hat_omega")


def test_a_verdict_the_law_does_not_reach_is_caught():
    rows, outcome = _device("motor-mfc1")
    early = dataclasses.replace(outcome, status="aborted", monitor="du_dt", time=149 / 200.0)
    law = _check("motor-mfc1", rows[:150], early)
    assert law.flag == "diverged@tick 149" and law.column == "verdict"
    assert "aborted (du_dt) after 150 ticks" in law.detail
    rows, outcome = _device("motor-aborted")  # the law aborts; a device that says completed is caught
    law = _check("motor-aborted", rows, dataclasses.replace(outcome, status="completed", monitor=None))
    assert law.column == "verdict" and law.tick == len(rows) - 1


def test_a_monitor_the_safety_routine_does_not_have_is_caught():
    rows, outcome = _device("motor-aborted")
    law = _check("motor-aborted", rows, dataclasses.replace(outcome, monitor="overspeed"))
    assert law.flag == f"diverged@tick {len(rows) - 1}" and "'overspeed' is none of the safety routine's" in law.detail


def test_the_monitors_a_run_can_name_are_the_documented_list():
    from labrunner.safety import MONITORS

    text = (ROOT / "docs" / "control-laws.md").read_text()
    assert all(f"`{name}`" in text for name in MONITORS)
    _, outcome = _device("motor-aborted")
    assert outcome.monitor == "du_dt" and outcome.monitor in MONITORS


def test_a_failed_run_is_checked_up_to_its_last_sample_and_an_empty_one_not_at_all():
    rows, outcome = _device("motor-mfc2")
    failed = dataclasses.replace(outcome, status="failed", message="stopped by the host")
    assert _check("motor-mfc2", rows[:77], failed).flag == "ok"
    assert _check("motor-mfc2", rows[:0], failed).flag == "not-checked"


CAMPAIGN = """
[campaign]
name = "motor-device-law"
rig = "motor-can.toml"
fs = 200.0
duration = 1.0
seed = 4

[controller]
kind = "mfc1"
output = "velocity"
gamma = 108.55
k_p = 30.0

[differentiator]
alpha = 4
beta = 4
omega_c = 150.0

[reference]
kind = "setpoints"
levels = [0.0, 20.0, 0.0]
transition = 0.3
hold = 0.2

[grid]
"controller.k_p" = { values = [20.0, 30.0] }
"""


_run = functools.partial(cli, cwd=ROOT, timeout=600)  # the real command, from the repository root


@pytest.mark.slow
@pytest.mark.parametrize(
    "faults, flag, arithmetic",
    [((), "ok", "float64"), (("--fault-law", "gamma=1.02"), "diverged", "float64"), (("--float32",), "ok", "float32")],
)
def test_the_flag_reaches_status_analyse_and_metrics_csv(tmp_path: Path, faults, flag, arithmetic):
    """… with the arithmetic each run was checked under (a FLOAT32 device: the float32 tolerance)."""
    with emulator_process(rig_file("motor-mfc1", "can"), faults) as config:
        (tmp_path / "motor-can.toml").write_text(rig_toml(config))
        (tmp_path / "campaign.toml").write_text(CAMPAIGN)
        done = _run("run", str(tmp_path / "campaign.toml"), "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    said = done.stderr if flag == "diverged" else done.stdout  # labrunner run's own last line
    assert f"law check (device loop): {2 if flag == 'ok' else 0} ok, {2 if flag != 'ok' else 0} diverged" in said
    status = json.loads(_run("status", str(tmp_path / "out"), "--json").stdout)["law_check"]
    assert status[flag] == 2 and sum(status[k] for k in ("ok", "diverged", "not-checked")) == 2
    assert status["arithmetic"] == {arithmetic: 2}
    text = _run("status", str(tmp_path / "out")).stdout
    assert f"law check (device loop): {2 if flag == 'ok' else 0} ok, {2 if flag != 'ok' else 0} diverged" in text
    assert f"(checked under {arithmetic}: 2)" in text
    analysed = _run("analyse", str(tmp_path / "out"), "--json")
    assert analysed.returncode == 0, analysed.stderr
    summary = json.loads(analysed.stdout)
    assert summary["law_check"][flag] == 2 and summary["law_check"]["arithmetic"] == {arithmetic: 2}
    table = pd.read_csv(Path(summary["metrics"][0]))
    assert all(str(f).startswith(flag) for f in table["law_check"])
    assert list(table["law_arithmetic"]) == [arithmetic] * 2
    report = Path(summary["report"]).read_text()
    assert f"checked under {arithmetic}: 2" in report and "<th>law_arithmetic</th>" in report
    if flag == "diverged":
        assert status["first_diverged"]["flag"].startswith("diverged@tick ")
        assert "the device did not run the law" in report and "diverged@tick" in report
    # the log's outcome record has the twin's shape (the check is in its diagnostics record), and a
    # ledger rebuilt from the logs alone still knows every run's check
    for log in (tmp_path / "out" / "runs").glob("*.mcap"):
        assert set(read_metadata(log)["outcome"]) <= {*OUTCOME_KEYS, "n_samples"}
    (tmp_path / "out" / "ledger.sqlite").unlink()
    assert _run("repair", str(tmp_path / "out"), "--campaign", str(tmp_path / "campaign.toml")).returncode == 0
    assert json.loads(_run("status", str(tmp_path / "out"), "--json").stdout)["law_check"] == status


SHIPPED = sorted((ROOT / "campaigns").rglob("*.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("path", SHIPPED, ids=[str(p.relative_to(ROOT / "campaigns")) for p in SHIPPED])
def test_the_emulated_device_passes_the_check_on_every_shipped_campaign(path):
    """Each shipped campaign's first point as a device-loop run (the reference executor on its
    twin), its first 4000 ticks at most: the law check passes."""
    from labrunner.campaign import spec
    from labrunner.errors import InvalidParameter

    campaign = spec.load(path)
    if campaign.guided is not None:
        pytest.skip("a guided campaign chooses its points while it runs")
    _, point = next(campaign.points())
    rig = load_rig(campaign.rig_ref)
    fs = campaign.fs
    duration = min(campaign.duration or 4000 / fs, 4000 / fs)
    try:
        data = description.build(point, rig.info, fs=fs, duration=duration, seed=2, rig_safety=campaign.rig_safety)
    except InvalidParameter as exc:  # per-run rig parameters (the fault campaigns): no device runs them
        assert "rig_parameters" in str(exc)
        pytest.skip(str(exc))
    run = executor.execute(data, rig)
    outcome = to_result(point, rig.info, fs, run.verdict, run.columns, {}).outcome
    law = lawcheck.check(
        point, rig.info, run.columns, outcome, fs=fs, duration=duration, seed=2, rig_safety=campaign.rig_safety
    )
    assert law.flag == "ok", law.detail
