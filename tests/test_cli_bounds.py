"""``labrunner bounds``: JSON equals the library's ``bounds``, bad input exits 2 with one line."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from labrunner.cli import main
from labrunner.stability import bounds

MOTOR = ["--a", "39.44", "--b", "108.55"]


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["bounds", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_matches_library(capsys):
    code, out, _ = run(
        capsys, "--case", "mfc2-motor", "--gamma", "119.405", "--delay", "0.035", *MOTOR, "--k-d", "20", "--json"
    )
    assert code == 0
    assert json.loads(out) == bounds("mfc2-motor", gamma=119.405, delay=0.035, a=39.44, b=108.55, k_d=20.0)
    assert set(json.loads(out)) == {"k_p", "k_d"}


def test_json_numeric(capsys):
    code, out, _ = run(
        capsys, "--case", "mfc1-motor", "--gamma", "108.55", "--delay", "0.01", *MOTOR, "--numeric", "--json"
    )
    result = json.loads(out)
    assert code == 0 and set(result) == {"k_p", "numeric"}
    assert result["numeric"]["k_p"] == pytest.approx(result["k_p"], rel=1e-6, abs=1e-6 * result["k_p"][1])


def test_null_when_nothing_is_stable(capsys):
    # k_d in the gap between the correct bound (π/2)γ/(ρδ) ≈ 44.9 and the printed (2.53) ≈ 52.0
    code, out, _ = run(
        capsys,
        "--case",
        "mfc2-ultralocal",
        "--gamma",
        "108.55",
        "--delay",
        "0.035",
        "--b",
        "108.55",
        "--k-d",
        "48",
        "--json",
    )
    assert code == 0 and json.loads(out)["k_p"] is None
    code, out, _ = run(
        capsys, "--case", "mfc2-ultralocal", "--gamma", "108.55", "--delay", "0.035", "--b", "108.55", "--k-d", "48"
    )
    assert code == 0 and "k_p: none stable at k_d = 48" in out


def test_human_output(capsys):
    code, out, _ = run(
        capsys, "--case", "mfc2-ultralocal", "--gamma", "1", "--delay", "0.01", "--rho", "1", "--k-d", "50", "--numeric"
    )
    assert code == 0
    assert "k_d in (0, 157.0796327)" in out and "k_p in (0, " in out and "numerical solver" in out


UL = ["--case", "mfc1-ultralocal"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([*UL, "--gamma", "1", "--delay", "0", "--rho", "1"], "delay: must be > 0, got 0.0"),
        ([*UL, "--gamma", "1", "--delay", "-0.1", "--rho", "1"], "delay: must be > 0, got -0.1"),
        ([*UL, "--gamma", "1", "--delay", "nan", "--rho", "1"], "delay: must be a finite number > 0, got nan"),
        ([*UL, "--gamma", "0", "--delay", "0.1", "--rho", "1"], "gamma: must be > 0, got 0.0"),
        ([*UL, "--gamma", "nan", "--delay", "0.1", "--rho", "1"], "gamma: must be a finite number > 0, got nan"),
        ([*UL, "--gamma", "1", "--delay", "0.1", "--rho", "-2"], "rho: must be > 0, got -2.0"),
        ([*UL, "--gamma", "1", "--delay", "0.1", "--rho", "nan"], "rho: must be a finite number > 0, got nan"),
        ([*UL, "--gamma", "1", "--delay", "0.1", "--b", "0"], "b: must be > 0, got 0.0"),  # --rho taken from --b
        ([*UL, "--gamma", "1", "--delay", "0.1"], "rho: is required for case mfc1-ultralocal (or give b)"),
        (
            ["--case", "mfc2-motor", "--gamma", "1", "--delay", "0.1", *MOTOR],
            "k_d: is required for the second-order case mfc2-motor",
        ),
        (
            ["--case", "mfc2-ultralocal", "--gamma", "1", "--delay", "0.1", "--rho", "1"],
            "k_d: is required for the second-order case",
        ),
        (
            ["--case", "mfc2-motor", "--gamma", "1", "--delay", "0.1", *MOTOR, "--k-d", "nan"],
            "k_d: must be finite, got nan",
        ),
        (
            ["--case", "mfc1-motor", "--gamma", "1", "--delay", "0.1", "--a", "nan", "--b", "2"],
            "a: must be finite, got nan",
        ),
        (["--case", "mfc1-motor", "--gamma", "1", "--delay", "0.1", "--b", "2"], "a: is required for case mfc1-motor"),
        (
            ["--case", "mfc1-motor", "--gamma", "1", "--delay", "0.1", *MOTOR, "--k-d", "3"],
            "k_d: is not used by the first-order case",
        ),
        (
            [
                "--case",
                "mfc2-second-order",
                "--gamma",
                "1",
                "--delay",
                "0.1",
                "--a0",
                "-1",
                "--a1",
                "1",
                "--b",
                "1",
                "--k-d",
                "1",
            ],
            "a0: must be >= 0 (thesis A.6), got -1.0",
        ),
        ([*UL, "--gamma", "abc", "--delay", "0.1", "--rho", "1"], "argument --gamma: must be a number > 0, got 'abc'"),
        (
            ["--case", "mfc9", "--gamma", "1", "--delay", "0.1", "--rho", "1"],
            "argument --case: invalid choice: 'mfc9' (choose from",
        ),
    ],
)
def test_bad_input_exits_2_with_one_line(capsys, args, message):
    """One line on stderr naming the parameter and what it accepts; nothing on stdout."""
    try:
        code = main(["bounds", *args])
    except SystemExit as exc:  # argparse usage errors (not a number, unknown case)
        code = exc.code
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and err.startswith("labrunner bounds: error: ") and message in err, err


def test_json_numeric_second_order(capsys):
    code, out, _ = run(
        capsys,
        "--case",
        "mfc2-ultralocal",
        "--gamma",
        "1",
        "--delay",
        "0.01",
        "--b",
        "1",
        "--k-d",
        "50",
        "--numeric",
        "--json",
    )
    result = json.loads(out)
    assert code == 0 and set(result) == {"k_p", "k_d", "numeric"} and set(result["numeric"]) == {"k_p", "k_d"}
    assert result == bounds("mfc2-ultralocal", gamma=1.0, delay=0.01, rho=1.0, k_d=50.0, numeric=True)  # rho = b
    for key in ("k_p", "k_d"):
        assert result["numeric"][key] == pytest.approx(result[key], rel=1e-6, abs=1e-6 * result[key][1])


def test_end_to_end_subprocess():
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "labrunner",
            "bounds",
            "--case",
            "mfc1-ultralocal",
            "--gamma",
            "2",
            "--delay",
            "0.01",
            "--rho",
            "3",
            "--json",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0
    assert json.loads(proc.stdout)["k_p"] == pytest.approx([0.0, 3.141592653589793 / 2 * 2 / 0.03])
    bad = subprocess.run(
        [
            sys.executable,
            "-m",
            "labrunner",
            "bounds",
            "--case",
            "mfc2-motor",
            "--gamma",
            "1",
            "--delay",
            "0.01",
            *MOTOR,
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert (
        bad.returncode == 2
        and bad.stderr.strip() == "labrunner bounds: error: k_d: is required for the second-order case mfc2-motor"
    )


def test_numeric_round_off_at_a_zero_bound_prints_as_zero(capsys):
    """The solver finds the lower k_p bound 0 to within ~1e-15; the text says 0, not 3.3e-15."""
    args = ("--case", "mfc1-motor", "--gamma", "108.55", "--delay", "0.035", *MOTOR, "--numeric")
    code, out, _ = run(capsys, *args, "--json")
    lo = json.loads(out)["numeric"]["k_p"][0]
    assert code == 0 and lo != 0.0 and abs(lo) < 1e-9  # the solver's own value, kept in JSON
    code, out, _ = run(capsys, *args)
    solver = out.split("numerical solver:")[1]
    assert code == 0 and "k_p in (0, 112.2725304)" in solver and "e-" not in solver
