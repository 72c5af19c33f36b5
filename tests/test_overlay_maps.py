"""Overlay plots of several runs (labrunner plot A.mcap B.mcap …) and the new map options: the
largest-current and per-sensor dB maps, and the robust colour scale."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrunner import engine
from labrunner.analysis.figures import map_metrics, with_db_columns
from labrunner.analysis.maps import colour_norm
from labrunner.cli import main
from labrunner.errors import InvalidParameter
from labrunner.logs import write_run
from labrunner.overlay import _labels, plot_overlay
from labrunner.rigs import registry

ROOT = Path(__file__).resolve().parents[1]
POINT = {
    "controller": {"kind": "mfc1", "output": "velocity", "gamma": 108.55, "k_p": 50.0},
    "differentiator": {"alpha": 9, "beta": 9, "N": 0, "omega_c": 200.0, "method": "midpoint"},
    "reference": {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 0.5, "hold": 0.2},
    "safety": {"max_du_dt": 120.0},
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("overlay")
    points = [
        {**POINT, "controller": {**POINT["controller"], "gamma": g, "k_p": k}}
        for g, k in ((108.55, 50.0), (10.0, 1000.0))
    ]
    with registry.load_rig("dcmotor-sim", search=[ROOT / "rigs"]) as rig:
        results = engine.run_batch(points, rig, fs=200.0, duration=1.6, seeds=[0, 0])
    paths = []
    for i, (p, r) in enumerate(zip(points, results)):
        path = folder / f"run{i}.mcap"
        write_run(
            path,
            metadata={
                "run": {"rig": "dcmotor-sim"},
                "config": p,
                "parameters": {
                    "controller.gamma": p["controller"]["gamma"],
                    "controller.k_p": p["controller"]["k_p"],
                    "campaign.fs": 200.0,
                },
            },
            fs=r.fs,
            signals=r.signals,
            outcome=r.outcome.as_dict(),
            channels=r.channels,
        )
        paths.append(path)
    assert [r.outcome.status for r in results] == ["completed", "aborted"]  # the second trips |du/dt|
    return paths


def test_overlay_draws_each_run_on_shared_output_and_input_panels(logs):
    fig = plot_overlay(logs)
    outputs, inputs = fig.axes
    assert outputs.get_ylabel().startswith("$\\Omega$") and inputs.get_ylabel() == "u [V]"
    labels = [line.get_label() for line in outputs.get_lines() if not line.get_label().startswith("_")]
    assert labels[1:] == ["gamma = 108.5, k_p = 50", "gamma = 10, k_p = 1000"]  # fs is equal: not shown
    assert labels[0].startswith("$\\Omega_r$")  # the first run's reference, dashed
    # the aborted run is shorter and ends in a cross on every panel
    lines = [line for line in inputs.get_lines() if line.get_marker() == "x"]
    assert len(lines) == 1


def test_plot_cli_overlays_several_logs(logs, tmp_path, capsys):
    out = tmp_path / "both.png"
    assert main(["plot", *map(str, logs), "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["plot", str(logs[0]), str(logs[1])]) == 0
    assert logs[0].with_name("run0-overlay.png").is_file()


def test_overlay_refuses_one_run_and_too_many():
    with pytest.raises(InvalidParameter, match="2 to 20"):
        plot_overlay(["a.mcap"])
    with pytest.raises(InvalidParameter, match="2 to 20"):
        plot_overlay(["a.mcap"] * 21)


def test_labels_fall_back_to_all_values_then_to_names():
    class Log:
        def __init__(self, params):
            self.metadata = {"parameters": params}

    same = [Log({"controller.k_p": 5.0}), Log({"controller.k_p": 5.0})]
    assert _labels(same, ["a", "b"]) == ["k_p = 5", "k_p = 5"]
    assert _labels([Log({}), Log({})], ["a", "b"]) == ["a", "b"]


def test_robust_colour_scale_ends_below_outliers_but_not_otherwise():
    z = np.concatenate([np.linspace(1.0, 2.0, 40), [50.0]])
    norm = colour_norm(z)
    assert norm.vmin == 1.0 and norm.vmax == pytest.approx(np.percentile(z, 95))
    plain = colour_norm(np.linspace(1.0, 2.0, 40))
    assert plain.vmax == 2.0
    assert colour_norm(np.array([1.0, 2.0, 50.0])).vmax == 50.0  # too few values to call one an outlier


def test_max_current_and_db_maps_only_where_they_mean_something():
    plate = pd.DataFrame(
        {"rms_error": [1e-5], "rms_e_y1": [1e-6], "rms_e_y2": [1e-5], "rms_e_y3": [np.nan], "max_current": [3.0]}
    )
    with_db = with_db_columns(plate, {"rms_error": "m"})
    assert with_db["rms_e_y1_db"].iloc[0] == pytest.approx(0.0) and with_db["rms_e_y2_db"].iloc[0] == pytest.approx(
        20.0
    )
    columns = [c for c, *_ in map_metrics("ê", with_db)]
    assert columns == ["rms_error", "input_energy", "max_current", "rms_e_y1_db", "rms_e_y2_db", "rms_e_y3_db"]
    motor = pd.DataFrame({"rms_error": [0.4], "rms_e_omega": [0.4], "max_current": [np.nan]})
    assert with_db_columns(motor, {"rms_error": "rad/s"}) is motor
    assert [c for c, *_ in map_metrics("e", motor)] == ["rms_error", "input_energy"]
