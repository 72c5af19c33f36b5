"""``labrunner inspect`` and ``labrunner plot`` (in-process, and once through the real command)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from matplotlib.figure import Figure
from mcap.reader import make_reader
from test_logs_support import ABORTED, CHANNELS, COMPLETED, metadata, motor_run

from labrunner.cli import main
from labrunner.logs import RunLogWriter, write_run
from labrunner.runplot import plot_run

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def aborted_run(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(
        path,
        metadata=metadata(),
        fs=200.0,
        signals=motor_run(),
        outcome=ABORTED,
        channels=CHANNELS,
        attachments={"campaign.toml": b"[campaign]\n"},
    )
    return path


@pytest.fixture
def torn_run(tmp_path):
    """A streamed run cut inside its last chunk: two complete blocks of 100 samples survive."""
    path = tmp_path / "torn.mcap"
    signals = motor_run(duration=1.5)
    with RunLogWriter(path, metadata=metadata("p-torn"), fs=200.0, channels=CHANNELS, flush_interval_s=0.0) as w:
        for k in range(0, 300, 100):
            w.write_block(k, {n: v[k : k + 100] for n, v in signals.items()})
        w.finish(COMPLETED)
    with open(path, "rb") as f:
        ends = sorted(c.chunk_start_offset + c.chunk_length for c in make_reader(f).get_summary().chunk_indexes)
    assert len(ends) == 3  # each flush writes one chunk of per-sample messages
    path.write_bytes(path.read_bytes()[: ends[1] + 40])
    return path


def test_inspect_json(aborted_run, capsys):
    assert main(["inspect", str(aborted_run), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["outcome"] == {**ABORTED, "n_samples": 1000}
    assert out["n_samples"] == 1000 and out["fs"] == 200.0 and out["torn"] is False
    assert out["signals"] == list(CHANNELS)
    assert out["metadata"]["config"]["controller"]["k_p"] == 50.0
    assert out["metadata"]["channels"]["u"] == {"role": "input", "unit": "V"}
    assert out["attachments"] == {"campaign.toml": 11}


def test_inspect_text(aborted_run, capsys):
    assert main(["inspect", str(aborted_run)]) == 0
    text = capsys.readouterr().out
    assert "aborted" in text and "monitor=du_dt" in text and "threshold=120.0" in text
    assert "1000 at 200 Hz, 5 s" in text and "u [V] (input)" in text and "TORN" not in text


def test_inspect_torn_says_so(torn_run, capsys):
    assert main(["inspect", str(torn_run), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["torn"] is True and out["outcome"] is None and out["n_samples"] == 200
    assert main(["inspect", str(torn_run)]) == 0
    text = capsys.readouterr().out
    assert "TORN" in text and "none (run did not finish)" in text


@pytest.mark.parametrize("command", ["inspect", "plot"])
def test_missing_and_corrupt_files_are_one_line_errors(tmp_path, capsys, command):
    assert main([command, str(tmp_path / "nope.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such run log" in err
    (tmp_path / "junk.mcap").write_bytes(b"\x00" * 100)
    assert main([command, str(tmp_path / "junk.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not an MCAP file" in err


def test_plot_writes_png(aborted_run, tmp_path, capsys):
    out = tmp_path / "run.png"
    assert main(["plot", str(aborted_run), "-o", str(out), "--dpi", "60"]) == 0
    assert out.read_bytes()[:8] == PNG and capsys.readouterr().out.strip() == str(out)
    assert main(["plot", str(aborted_run)]) == 0  # default: beside the log
    assert aborted_run.with_suffix(".png").read_bytes()[:8] == PNG


def test_plot_bad_output(aborted_run, tmp_path):
    assert main(["plot", str(aborted_run), "-o", str(tmp_path / "no" / "dir.png")]) == 2
    assert main(["plot", str(aborted_run), "-o", str(tmp_path / "x.unknownformat")]) == 2
    assert main(["plot", str(aborted_run), "--dpi", "0"]) == 2


def test_plot_run_panels_and_abort_markers(aborted_run):
    fig = plot_run(aborted_run)
    assert isinstance(fig, Figure)
    outputs, inputs, estimates = fig.axes
    assert [l.get_label() for l in outputs.get_lines() if not l.get_label().startswith("_")] == [
        r"$\Omega$",
        r"$\Omega_r$",
    ]
    assert outputs.get_lines()[1].get_linestyle() == "--"
    assert outputs.get_lines()[0].get_color() == outputs.get_lines()[1].get_color()
    assert "[V]" in inputs.get_ylabel() and "[rad/s]" in outputs.get_ylabel()
    assert estimates.get_lines()[0].get_label() == r"$\hat{f}_{\Omega}$"
    signals = motor_run()
    assert np.array_equal(inputs.get_lines()[0].get_ydata(), signals["u"])
    for ax in fig.axes:  # a vertical line at the abort time on every panel
        assert any(list(l.get_xdata()) == [2.6, 2.6] for l in ax.get_lines())
    cross = [l for l in inputs.get_lines() if l.get_marker() == "x"]
    assert len(cross) == 1 and cross[0].get_xdata()[0] == pytest.approx(2.6)
    assert "aborted by du_dt at t = 2.600 s" in fig.get_suptitle()


def test_title_names_the_grid_values(tmp_path):
    path = tmp_path / "point.mcap"
    meta = {**metadata(), "parameters": {"controller.gamma": 108.55, "controller.k_p": 50.0}}
    write_run(path, metadata=meta, fs=200.0, signals=motor_run(), outcome=ABORTED, channels=CHANNELS)
    assert plot_run(path).get_suptitle().startswith("p-0042 ($\\gamma$ = 108.5, $k_\\mathrm{p}$ = 50)\naborted")


def test_plot_into_given_figure_and_torn(torn_run):
    parent = Figure()
    sub = parent.subfigures(1, 2)[1]
    assert plot_run(torn_run, sub) is sub
    assert "torn log" in sub.get_suptitle() and len(sub.axes) == 3
    assert len(sub.axes[0].get_lines()[0].get_xdata()) == 200


def test_real_command(aborted_run, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "inspect", str(aborted_run), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["outcome"]["monitor"] == "du_dt"
    png = tmp_path / "sub.png"
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "plot", str(aborted_run), "-o", str(png), "--dpi", "50"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert png.read_bytes()[:8] == PNG


def test_plot_draws_small_lengths_in_mm(tmp_path):
    gap = 5.5e-3 - 3.5e-3 * np.linspace(0, 1, 50)
    path = tmp_path / "plate.mcap"
    write_run(
        path,
        metadata={},
        fs=100.0,
        signals={"h": gap, "ref_h": gap, "i": np.full(50, 3.0)},
        outcome=COMPLETED,
        channels={"h": {"role": "controlled", "unit": "m"}, "i": {"role": "input", "unit": "A"}},
    )
    outputs, inputs = plot_run(path).axes
    assert outputs.get_ylabel() == "outputs [mm]" and inputs.get_ylabel() == "inputs [A]"
    assert np.allclose(outputs.get_lines()[0].get_ydata(), 1e3 * gap)


def test_plot_without_roles_still_shows_every_kind(tmp_path):
    path = tmp_path / "plain.mcap"
    signals = motor_run(duration=1.0)
    write_run(path, metadata={}, fs=200.0, signals=signals, outcome=COMPLETED)  # roles from names only
    panels = [[l.get_label() for l in ax.get_lines()] for ax in plot_run(path).axes]
    assert panels == [[r"$\Omega$", r"$\Omega_r$"], [r"$\hat{f}_{\Omega}$"], [r"$\theta$", "u"]]


def test_aborted_run_is_drawn_on_its_planned_time_axis(tmp_path):
    """The engine ends an aborted run's signals at the abort sample; the plot keeps the planned
    duration (run.duration) on its time axis and greys out the part the run never reached."""
    signals = {name: values[:521] for name, values in motor_run().items()}  # up to the abort at 2.6 s
    meta = metadata()
    meta["run"]["duration"] = 3.5  # the run reached 74 % of it: one time axis for all
    path = tmp_path / "cut.mcap"
    write_run(path, metadata=meta, fs=200.0, signals=signals, outcome=ABORTED, channels=CHANNELS)
    fig = plot_run(path)
    assert len(fig.axes) == 3  # no context strip
    for ax in fig.axes:
        assert ax.get_xlim() == (0.0, 3.5)
        (grey,) = ax.patches
        assert grey.get_x() == pytest.approx(2.6) and grey.get_x() + grey.get_width() == pytest.approx(3.5)
    del meta["run"]["duration"]  # a log without a planned duration ends at its last sample
    write_run(path, metadata=meta, fs=200.0, signals=signals, outcome=ABORTED, channels=CHANNELS)
    assert plot_run(path).axes[0].get_xlim() == (0.0, 520 / 200.0)


def test_early_abort_is_zoomed_with_the_planned_run_as_context(tmp_path):
    """A run aborted at 0.675 s of 5 s fills 13 % of a 5 s axis: the panels zoom to the abort (10 %
    margin) and a strip above them shows the planned 5 s, the part never reached and the zoom."""
    signals = {name: values[:136] for name, values in motor_run().items()}
    meta = metadata()
    meta["run"]["duration"] = 5.0
    path = tmp_path / "early.mcap"
    write_run(path, metadata=meta, fs=200.0, signals=signals, outcome={**ABORTED, "time": 0.675}, channels=CHANNELS)
    fig = plot_run(path)
    *panels, context = fig.axes
    assert len(panels) == 3
    for ax in panels:
        assert ax.get_xlim() == pytest.approx((0.0, 0.675 * 1.1))
        assert any(list(l.get_xdata()) == [0.675, 0.675] for l in ax.get_lines())
    assert context.get_xlim() == (0.0, 5.0) and context.get_position().y0 > panels[0].get_position().y1
    grey, window = context.patches
    assert grey.get_x() == pytest.approx(0.675) and grey.get_x() + grey.get_width() == pytest.approx(5.0)
    assert window.get_x() == 0.0 and window.get_width() == pytest.approx(0.675 * 1.1) and not window.get_fill()
    assert "aborted at 0.675 s (14%)" in context.get_title(loc="left")
    assert np.array_equal(context.get_lines()[0].get_ydata(), signals["omega"])


def test_inspect_into_a_closed_pipe_is_quiet(aborted_run):
    """``labrunner inspect RUN.mcap --json | head -1``: the reader leaves early; no traceback."""
    done = subprocess.Popen(
        [sys.executable, "-m", "labrunner", "inspect", str(aborted_run), "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    done.stdout.close()  # the reader is gone before the first byte
    err = done.stderr.read().decode()
    assert done.wait(timeout=120) == 141 and "Traceback" not in err and "Exception ignored" not in err


def test_each_estimated_quantity_gets_its_own_panel(tmp_path):
    """f̂ [m/s²], ê [m] and ê̇ [m/s] of the plate differ by orders of magnitude: one panel each."""
    n = 50
    signals = {"y1": np.full(n, 2e-3), "ref_y1": np.full(n, 2e-3), "i1": np.full(n, 1.7),
               "f_hat_y1": np.full(n, 9.81), "e_hat_y1": np.full(n, 1e-6), "de_hat_y1": np.full(n, 1e-4),
               "f_hat_y2": np.full(n, 9.7)}  # fmt: skip
    path = tmp_path / "plate.mcap"
    write_run(
        path,
        metadata={},
        fs=100.0,
        signals=signals,
        outcome=COMPLETED,
        channels={"y1": {"role": "controlled", "unit": "m"}, "i1": {"role": "input", "unit": "A"}},
    )
    panels = [[l.get_label() for l in ax.get_lines()] for ax in plot_run(path).axes]
    assert panels == [["y1", "ref_y1"], ["i1"], ["f_hat_y1", "f_hat_y2"], ["e_hat_y1"], ["de_hat_y1"]]
