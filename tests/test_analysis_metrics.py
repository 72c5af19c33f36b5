"""Metrics against hand-computed values (thesis Sec. 3.4.1 RMS, 3.5.1 input energy E(u) = Σu²)."""

import math

import numpy as np
import pytest

from labrunner.metrics import Roles, run_metrics


def test_single_output_hand_values():
    signals = {"e_omega": np.array([1.0, -2.0, 2.0, 0.0]), "u": np.array([3.0, -4.0, 0.0, 1.0])}
    m = run_metrics(signals, Roles(errors=("e_omega",), inputs=("u",)))
    assert m["rms_error"] == pytest.approx(math.sqrt((1 + 4 + 4 + 0) / 4))  # 1.5
    assert m["rms_error"] == pytest.approx(1.5)
    assert m["input_energy"] == pytest.approx(9 + 16 + 0 + 1)
    assert m["max_abs_input"] == 4.0
    assert m["rms_e_omega"] == pytest.approx(1.5)
    assert m["n_samples"] == 4
    assert math.isnan(m["max_current"]) and math.isnan(m["rms_error_hat"])


def test_plate_per_output_and_currents():
    e1, e2, e3 = np.array([1.0, 1.0]), np.array([0.0, 2.0]), np.array([3.0, -1.0])
    i = {f"i{j}": np.array([0.5 * j, -1.0 * j]) for j in range(1, 5)}
    signals = {
        "e_y1": e1,
        "e_y2": e2,
        "e_y3": e3,
        **i,
        "e_hat_y1": np.array([2.0, 0.0]),
        "e_hat_y2": np.zeros(2),
        "e_hat_y3": np.zeros(2),
    }
    roles = Roles(
        errors=("e_y1", "e_y2", "e_y3"),
        inputs=tuple(i),
        currents=tuple(i),
        error_hats=("e_hat_y1", "e_hat_y2", "e_hat_y3"),
    )
    m = run_metrics(signals, roles)
    assert m["rms_e_y1"] == pytest.approx(1.0)
    assert m["rms_e_y2"] == pytest.approx(math.sqrt(2.0))
    assert m["rms_e_y3"] == pytest.approx(math.sqrt(5.0))
    assert m["rms_error"] == pytest.approx(math.sqrt((1 + 1 + 0 + 4 + 9 + 1) / 6))
    assert m["rms_e_hat_y1"] == pytest.approx(math.sqrt(2.0))
    assert m["rms_error_hat"] == pytest.approx(math.sqrt(4 / 6))
    # energy per input: Σ (0.5j)² + j² = 1.25 j²
    for j in range(1, 5):
        assert m[f"energy_i{j}"] == pytest.approx(1.25 * j * j)
    assert m["input_energy"] == pytest.approx(1.25 * (1 + 4 + 9 + 16))
    assert m["max_current"] == 4.0 and m["max_abs_input"] == 4.0


def test_torn_run_cuts_to_shortest_channel():
    signals = {"e_omega": np.array([2.0, 2.0, 7.0]), "u": np.array([1.0, 1.0])}
    m = run_metrics(signals, Roles(errors=("e_omega",), inputs=("u",)))
    assert m["n_samples"] == 2 and m["rms_error"] == pytest.approx(2.0) and m["input_energy"] == pytest.approx(2.0)


def test_roles_from_log_channels_with_rig_units_as_fallback():
    from labrunner.analysis.table import roles_of

    channels = {
        "q": {"role": "output", "unit": "l/min"},
        "i": {"role": "input", "unit": ""},
        "e_q": {"role": "error", "unit": ""},
        "e_hat_q": {"role": "estimate"},
        "f_hat_q": {"role": "estimate"},
        "ref_q": {"role": "reference"},
    }
    roles = roles_of(channels, {"i": "A", "q": "l/min"})
    assert roles == Roles(errors=("e_q",), inputs=("i",), error_hats=("e_hat_q",), currents=("i",))
    assert roles_of(channels).currents == ()  # no unit anywhere: not known to be a current


def test_an_open_loop_step_at_the_limit_is_not_flagged_oscillating(tmp_path):
    """The ±12 V identification steps of thesis Sec. 3.2 on the motor twin: u sits at the limit for 75 % of
    the run by command, which the detector alone reads as a loop that lost authority (pinned). Its callers
    (the engine's metrics, the analysis reading the logs again) run it on closed loops only, so neither
    flags these runs; the same step under the closed-loop metrics (the rig's input limits given) is."""
    import json
    from pathlib import Path

    from labrunner.analysis.table import log_metrics
    from labrunner.campaign.ledger import Ledger
    from labrunner.cli import main
    from labrunner.logs import read_run
    from labrunner.metrics import closes_loop

    campaign = Path(__file__).resolve().parents[1] / "campaigns" / "dcmotor-identification.toml"
    out = tmp_path / "ident"
    assert main(["run", str(campaign), "--out", str(out), "--workers", "1"]) == 0
    with Ledger.open_readonly(out) as ledger:
        rows = list(ledger.rows(("done",)))
    assert len(rows) == 4
    pinned = 0
    for row in rows:
        metrics = json.loads(row["metrics_json"])
        assert "oscillating" not in metrics and "pinned_share" not in metrics, metrics
        log = out / "runs" / f"{row['id']}.mcap"
        again = log_metrics(str(log), limits={"u": (-12.0, 12.0)})
        assert "error" not in again and "oscillating" not in again
        run = read_run(str(log))
        assert not closes_loop(run.metadata["config"])
        signals = {c: run.frame[c].to_numpy() for c in run.frame.columns}
        roles = Roles(errors=("e_u_cmd",), inputs=("u",), input_limits=((-12.0, 12.0),))
        closed = run_metrics(signals, roles, fs=float(run.fs))  # what the callers skip
        pinned += closed["oscillating"] == 1.0 and closed["pinned_share"] == pytest.approx(0.75)
    assert pinned == 2  # the ±12 V steps; the ±6 V ones never reach the limit
    assert closes_loop({"controller": {"kind": "mfc1"}}) and closes_loop(None)
    assert not closes_loop({"controller": {"kind": "valve-ffc"}})
