"""``labrunner differentiator``: JSON keys and values, summary, and bad input → exit 2, one line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from labrunner.cli import main
from labrunner.differentiators import design
from labrunner.differentiators.spectra import cost_db


def run_json(capsys, *argv: str) -> dict:
    assert main(["differentiator", *argv, "--json"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    return json.loads(out)


def test_json_thesis_design(capsys):
    info = run_json(capsys, "--alpha", "9", "--beta", "9", "--omega-c", "200", "--fs", "200")
    for key in ("n_s", "window_s", "delay_s", "discrete_delay_s", "omega_c_actual", "order", "method", "weights"):
        assert key in info
    assert "cost_db" not in info
    assert info["n_s"] == 14 and info["window_s"] == 0.07
    assert info["delay_s"] == pytest.approx(0.035) and info["discrete_delay_s"] == pytest.approx(0.0325)
    assert info["order"] == 1 and info["method"] == "midpoint"
    d = design(alpha=9, beta=9, omega_c=200, fs=200)
    np.testing.assert_array_equal(info["weights"], d.weights(1))  # full float precision round trip
    assert info["omega_c_actual"] == d.omega_c_actual
    # newest sample first, aligned at discrete_delay_s: α = β is exact for x = t², x' = 2t
    times_newest_first = 1.0 - np.arange(len(info["weights"])) / 200
    estimate = np.dot(info["weights"], times_newest_first**2)
    assert estimate == pytest.approx(2 * (1.0 - info["discrete_delay_s"]), rel=1e-12)


def test_json_with_cost_order_method_and_window(capsys):
    argv = ["--alpha", "4", "--beta", "4", "--omega-c", "840", "--fs", "32000", "--order", "2", "--cost"]
    info = run_json(capsys, *argv, "--method", "trapezoidal")
    assert info["n_s"] == 261 and len(info["weights"]) == 262
    d = design(alpha=4, beta=4, omega_c=840, fs=32000, method="trapezoidal")
    assert info["cost_db"] == pytest.approx(cost_db(d, 2))
    info = run_json(
        capsys,
        "--alpha",
        "2",
        "--beta",
        "3",
        "--N",
        "1",
        "--theta",
        "0.5",
        "--window",
        "0.145",
        "--fs",
        "200",
        "--order",
        "0",
    )
    assert info["n_s"] == 29 and info["delay_s"] == pytest.approx(0.25 * 0.145)
    assert sum(info["weights"]) == pytest.approx(1.0)


def test_summary_is_readable(capsys):
    assert main(["differentiator", "--alpha", "6", "--beta", "6", "--omega-c", "200", "--fs", "200", "--cost"]) == 0
    out = capsys.readouterr().out
    assert "n_s = 9" in out and "22.5 ms continuous" in out and "J_1 =" in out and "newest sample first" in out


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--alpha", "nan", "--beta", "1", "--window", "0.1"], "alpha: must be a finite number > -1, got nan"),
        (["--alpha", "2", "--beta", "inf", "--window", "0.1"], "beta: must be a finite number > -1, got inf"),
        (
            ["--alpha", "0.5", "--beta", "2", "--window", "0.1", "--order", "2"],
            "alpha: must be > n - 1 = 1 for derivative order 2",
        ),
        (
            ["--alpha", "2", "--beta", "1", "--window", "0.1", "--order", "2"],
            "beta: must be > n - 1 = 1 for derivative order 2",
        ),
        (["--alpha", "-2", "--beta", "2", "--window", "0.1"], "alpha: must be > -1 and <= 200, got -2.0"),
        (["--alpha", "2", "--beta", "2", "--window", "0.1", "--N", "-1"], "N: must be an integer in 0..20, got -1"),
        (["--alpha", "2", "--beta", "2", "--window", "0.1", "--N", "1.5"], "--N: must be an integer >= 0, got '1.5'"),
        (["--alpha", "2", "--beta", "2"], "omega_c: give exactly one of omega_c [rad/s] and window [s], got neither"),
        (
            ["--alpha", "2", "--beta", "2", "--window", "0.1", "--omega-c", "50"],
            "exactly one of omega_c [rad/s] and window [s], got both",
        ),
        (
            ["--alpha", "9", "--beta", "9", "--omega-c", "900"],
            "omega_c: must be <= 568.32 rad/s (n_s >= 5 at fs = 200 Hz: a realised cutoff <= Nyquist",
        ),
        (
            ["--alpha", "9", "--beta", "9", "--window", "0.02"],
            "window: must be >= 0.025 s (n_s >= 5 at fs = 200 Hz: a realised cutoff <= Nyquist",
        ),
        (["--alpha", "2", "--beta", "2", "--window", "0.005"], "window: must be >= 0.01 s (n_s >= 2 samples"),
        (["--alpha", "2", "--beta", "2", "--omega-c", "1000"], "omega_c: must be <= 391.487 rad/s (n_s >= 2 samples"),
        (["--alpha", "2", "--beta", "2", "--window", "-1"], "window: must be > 0, got -1.0"),
        (["--alpha", "2", "--beta", "2", "--window", "nan"], "window: must be a finite number > 0, got nan"),
        (["--alpha", "2", "--beta", "2", "--omega-c", "-5"], "omega_c: must be > 0, got -5.0"),
        (["--alpha", "2", "--beta", "2", "--window", "0.1", "--order", "-1"], "order: must be an integer >= 0, got -1"),
        (
            ["--alpha", "2", "--beta", "2", "--window", "0.1", "--order", "x"],
            "--order: must be an integer >= 0, got 'x'",
        ),
        (["--alpha", "2", "--beta", "2", "--window", "0.1", "--theta", "0.5"], "theta: is only a parameter for N > 0"),
        (
            ["--alpha", "2", "--beta", "2", "--window", "0.1", "--N", "1", "--theta", "2"],
            "theta: must be in [-1, 1], got 2.0",
        ),
        (
            ["--alpha", "2", "--beta", "2", "--window", "0.1", "--N", "1", "--theta", "nan"],
            "theta: must be in [-1, 1], got nan",
        ),
        (
            ["--alpha", "2", "--beta", "2", "--window", "0.1", "--method", "simpson"],
            "--method: invalid choice: 'simpson' (choose from",
        ),
        (
            ["--alpha", "1.5", "--beta", "2", "--window", "0.1", "--order", "2", "--method", "trapezoidal"],
            "method: trapezoidal samples the window ends, where g^(2) is infinite; needs min(alpha, beta) >= 2",
        ),
        (["--alpha", "x", "--beta", "2", "--window", "0.1"], "--alpha: must be a number > -1, got 'x'"),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, argv, fragment):
    """Each message names the parameter and its allowed range, on one line; nothing on stdout."""
    try:
        code = main(["differentiator", *argv, "--fs", "200"])
    except SystemExit as exc:  # argparse's own usage errors (not a number)
        code = exc.code
    assert code == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and fragment in err, err


@pytest.mark.parametrize(
    "fs, fragment", [("-200", "fs: must be > 0, got -200.0"), ("nan", "fs: must be a finite number > 0")]
)
def test_bad_sampling_rate_exits_2(capsys, fs, fragment):
    assert main(["differentiator", "--alpha", "2", "--beta", "2", "--window", "0.1", "--fs", fs]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and fragment in err


def test_real_command_end_to_end():
    ok = subprocess.run(
        [
            sys.executable,
            "-m",
            "labrunner",
            "differentiator",
            "--alpha",
            "6",
            "--beta",
            "6",
            "--omega-c",
            "200",
            "--fs",
            "200",
        ]
        + ["--json"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert ok.returncode == 0 and json.loads(ok.stdout)["n_s"] == 9
    bad = subprocess.run(
        [sys.executable, "-m", "labrunner", "differentiator", "--alpha", "6", "--beta", "6", "--fs", "200"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "omega_c" in bad.stderr


def test_output_into_a_closed_pipe_ends_quietly():
    """`labrunner … --json | head` must not print a traceback when the reader stops early."""
    read, write = os.pipe()
    os.close(read)  # the reader is gone before anything is written
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "labrunner",
            "differentiator",
            "--alpha",
            "9",
            "--beta",
            "9",
            "--omega-c",
            "200",
            "--fs",
            "200",
            "--json",
        ],
        stdout=write,
        stderr=subprocess.PIPE,
        text=True,
        timeout=60,
    )
    os.close(write)
    assert done.returncode == 141 and done.stderr == ""


def test_a_broken_pipe_elsewhere_is_not_hidden(monkeypatch, capsys):
    from labrunner.cli import differentiator_cmd

    def broken(args):
        raise BrokenPipeError(32, "Broken pipe", "/dev/rig0")

    monkeypatch.setattr(differentiator_cmd, "run", broken)
    assert main(["differentiator", "--alpha", "9", "--beta", "9", "--omega-c", "200", "--fs", "200"]) == 1
    assert capsys.readouterr().err == "labrunner differentiator: error: /dev/rig0: Broken pipe\n"


def test_a_window_whose_normalisation_vanishes_is_refused(capsys, tmp_path):
    """α = 3, β = 1 at n_s = 2: the second mid-point u = 3/4 = α/(α+β) is the kernel's peak, where
    g′ = 0, so Φ_1 = −g′(3/4)·t_s = 0 and the weights would be inf/nan. The design, the command and
    a campaign refuse it, naming the window and the shortest one that works; order 0 is fine."""
    from labrunner.errors import InvalidParameter

    d = design(alpha=3, beta=1, omega_c=400, fs=200)
    assert d.n_s == 2 and d.check_weights(0) == 0 and np.isclose(d.weights(0).sum(), 1.0)
    for check in (d.weights, d.check_weights):
        with pytest.raises(InvalidParameter, match=r"n_s = 2 samples .* order 1 .* needs n_s >= 3") as err:
            check(1)
        assert err.value.field == "window"
    assert np.isfinite(design(alpha=3, beta=1, window=3 / 200, fs=200).weights(1)).all()
    assert main(["differentiator", "--alpha", "3", "--beta", "1", "--omega-c", "400", "--fs", "200"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "window: n_s = 2 samples cannot estimate derivative order 1" in err
    root = os.path.join(os.path.dirname(__file__), "..")
    text = open(os.path.join(root, "campaigns", "quickstart.toml"), encoding="utf-8").read()
    text = (
        text.replace("alpha = 9", "alpha = 3")
        .replace("beta = 9", "beta = 1")
        .replace("omega_c = 200.0 ", "omega_c = 400.0 ")
    )
    shutil.copytree(os.path.join(root, "rigs"), tmp_path / "rigs")
    (tmp_path / "short.toml").write_text(text)
    assert main(["run", str(tmp_path / "short.toml"), "--out", str(tmp_path / "out")]) == 2
    assert "differentiator.window: n_s = 2 samples" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()  # refused before anything was created
