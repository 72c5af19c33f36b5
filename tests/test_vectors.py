"""Conformance vectors (docs/control-laws.md): ``labrunner vectors`` regenerates the shipped set
byte for byte, and an implementation written from the document alone (labrunner/rigs/device/doclaw.py,
plain per-sample Python, none of labrunner's control code) reproduces every vector."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from labrunner.rigs.device import description, doclaw, f32bound, lawcheck, vectors
from labrunner.rigs.device.f32bound import Bounded
from labrunner.rigs.device.vectors import CASES
from labrunner.rigs.registry import load_rig

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "docs" / "vectors"


def _same_text_but_last_bits(got: str, want: str, rtol: float, what: str) -> None:
    """Equal token for token, numbers within ``rtol`` of the larger magnitude (the design code's float64
    results differ in their last bits between CPUs: numpy's SIMD paths round exp/pow differently on
    AVX-512 and AVX2 machines)."""
    split = re.compile(r"[\s,=\[\]:]+")
    got_lines, want_lines = got.splitlines(), want.splitlines()
    assert len(got_lines) == len(want_lines), what
    for n, (a, b) in enumerate(zip(got_lines, want_lines, strict=True)):
        ta, tb = split.split(a), split.split(b)
        assert len(ta) == len(tb), f"{what} line {n + 1}"
        for x, y in zip(ta, tb, strict=True):
            try:
                fx, fy = float(x), float(y)
            except ValueError:
                assert x == y, f"{what} line {n + 1}: {x!r} != {y!r}"
                continue
            same = fx == fy or (math.isnan(fx) and math.isnan(fy))
            assert same or abs(fx - fy) <= rtol * max(abs(fx), abs(fy)), f"{what} line {n + 1}: {x} != {y}"


def test_the_shipped_vectors_are_what_labrunner_vectors_writes(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "vectors", "--out", str(tmp_path)], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(CASES) == sorted(p.name for p in SHIPPED.iterdir())
    for case in CASES:
        got, want = tmp_path / case, SHIPPED / case
        # the shipped .bin is what its .txt says, and the .txt is what this machine computes
        assert (
            vectors.description_text((want / "description.bin").read_bytes()) == (want / "description.txt").read_text()
        )
        assert len((got / "description.bin").read_bytes()) == len((want / "description.bin").read_bytes()), case
        for name, rtol in (("description.txt", 1e-12), ("verdict.txt", 1e-9)):
            _same_text_but_last_bits((got / name).read_text(), (want / name).read_text(), rtol, f"{case}/{name}")
        header = (want / "vector.csv").read_text().splitlines()[0]
        assert (got / "vector.csv").read_text().splitlines()[0] == header
        a, b = (np.loadtxt(f / "vector.csv", delimiter=",", skiprows=1, ndmin=2) for f in (got, want))
        # a law's cancellations near 0: the tolerance of the column; a column that is 0 in exact arithmetic
        # holds only rounding noise (|x| ~ 1e-16, its last bits change with the BLAS's thread count), hence
        # the absolute floor, far below any value a law or a rig computes
        scale = np.maximum(np.nanmax(np.abs(b), axis=0), 1e-4)
        assert a.shape == b.shape and bool(np.all((np.abs(a - b) <= 1e-9 * scale) | (np.isnan(a) & np.isnan(b)))), case


def test_the_last_bits_comparison_fails_on_a_real_difference():
    _same_text_but_last_bits("w = [1.0000000000000002, 2]", "w = [1, 2]", 1e-12, "ulp")
    with pytest.raises(AssertionError):
        _same_text_but_last_bits("w = [1.01, 2]", "w = [1, 2]", 1e-12, "gain")
    with pytest.raises(AssertionError):
        _same_text_but_last_bits("KIND mfc2", "KIND mfc1", 1e-12, "kind")


def test_every_kind_the_device_loop_accepts_has_a_vector():
    kinds = {description.decode((SHIPPED / c / "description.bin").read_bytes()).kind for c in CASES}
    assert kinds == set(description.DEVICE_KINDS)


def _verdict(path: Path) -> dict[str, str]:
    return dict(line.split(" = ", 1) for line in path.read_text().splitlines())


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_implementation_from_the_document_reproduces_the_vector(case):
    folder = SHIPPED / case
    d = description.decode((folder / "description.bin").read_bytes())
    header = (folder / "vector.csv").read_text().splitlines()[0].split(",")[1:]
    expected = np.loadtxt(folder / "vector.csv", delimiter=",", skiprows=1, ndmin=2)[:, 1:]
    inputs, outputs = header[: d.n_inputs], header[d.n_inputs : d.n_inputs + d.n_outputs]
    np.testing.assert_array_equal(expected[:, d.n_inputs : d.n_inputs + d.n_outputs], d.sensor_table[: len(expected)])
    rows, verdict = doclaw.run(d, inputs, outputs)
    assert rows.shape == expected.shape
    want = _verdict(folder / "verdict.txt")
    if want["monitor"] in lawcheck.NON_FINITE:  # the estimates of the faulty tick: NaN or a number
        free = lawcheck.free_at_fault(header, load_rig(CASES[case].rig).info)
        rows[-1, free] = expected[-1, free]
    scale = np.nanmax(np.abs(expected), axis=0) + 1e-300
    close = np.isclose(rows, expected, rtol=1e-9, atol=1e-9 * scale, equal_nan=True)
    if not close.all():  # a cancellation (f̂ = D_n x − γ Σ ŵ_0 v, the MBC's η̂ + g): 1e-9 of the magnitude of the
        _, bounded = doclaw.run(d, inputs, outputs, dtype=Bounded)  # terms it is computed from (bound / u)
        close |= np.abs(rows - expected) <= 1e-9 * bounded["bounds"] / f32bound.U
    for j, name in enumerate(header):
        assert close[:, j].all(), f"{name}: doc law {rows[~close[:, j], j]}, vector {expected[~close[:, j], j]}"
    assert verdict["status"] == want["status"] and int(want["samples"]) == len(rows)
    if want["status"] == "aborted":
        assert verdict["monitor"] == want["monitor"]
        for key in ("time", "value", "threshold"):
            if math.isnan(float(want[key])):
                assert math.isnan(verdict[key]), key
            else:
                assert verdict[key] == pytest.approx(float(want[key]), rel=1e-9), key
    else:
        assert want["monitor"] == "nan" and math.isnan(float(want["time"]))


@pytest.mark.parametrize(
    "args, message",
    [
        (["--case", "pid-motor"], "--case: must be one of mfc1-motor-velocity, "),
        (["--out", "FILE"], "exists and is not a directory"),
    ],
)
def test_bad_arguments_give_one_line_and_write_nothing(tmp_path, args, message):
    (tmp_path / "FILE").write_text("x")
    argv = ["--out", str(tmp_path / "new")] + [str(tmp_path / a) if a == "FILE" else a for a in args]
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "vectors", *argv], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 2 and message in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "new").exists() and (tmp_path / "FILE").read_text() == "x"
