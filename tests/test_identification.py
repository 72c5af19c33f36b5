"""Identification of a and b (thesis Sec. 3.2) on signals from the exact ZOH discretisation of
θ̈ = −a θ̇ + b u (plus an optional Coulomb friction), the thesis's four steps at 100 Hz."""

import numpy as np
import pytest

from labrunner.errors import InvalidParameter
from labrunner.identification import identify_friction, identify_signals

A, B, FS = 39.44, 108.55, 100.0


def simulate(level: float, *, friction: float = 0.0, k_step: int = 50, K: int = 200, theta0: float = 0.3):
    """Exact sampled response of Ω̇ = −aΩ + b·u − F·sign(u), θ̇ = Ω to a held step of ``level`` V."""
    ts = 1.0 / FS
    u = np.where(np.arange(K) >= k_step, level, 0.0)
    e = np.exp(-A * ts)
    g1, g2 = (1 - e) / A, (ts - (1 - e) / A) / A
    theta, omega = np.empty(K), 0.0
    th = theta0
    for k in range(K):
        theta[k] = th
        drive = B * u[k] - friction * np.sign(u[k])
        th, omega = th + g1 * omega + g2 * drive, e * omega + g1 * drive
    return theta, u


@pytest.mark.parametrize("level", [-12.0, -6.0, 6.0, 12.0])
def test_recovers_a_and_b_within_one_percent_per_step(level):
    est = identify_signals(*simulate(level), FS)
    assert est.a == pytest.approx(A, rel=0.01)
    assert est.b == pytest.approx(B, rel=0.01)
    assert est.n_samples == 200 - 19  # n_s = 19 for α = β = 6, ω_c = 50 rad/s at 100 Hz


def test_input_timing_matters():
    """Pairing θ with the input one sample off gives a visibly wrong b: the regression is sensitive
    to the input's timing, which is why u is aligned to the mid-point of the θ estimate."""
    theta, u = simulate(12.0)
    good = identify_signals(theta, u, FS)
    shifted = identify_signals(theta[1:], u[:-1], FS)  # one sample off: visibly wrong
    assert abs(good.b / B - 1) < 0.01 < abs(shifted.b / B - 1)


def test_coulomb_friction_biases_b_by_its_share_of_the_input():
    """With η = −F·sign(u) the model sees b_eff = b − F/|u|: the bias the thesis's friction causes."""
    F = 60.0
    for level in (6.0, 12.0):
        est = identify_signals(*simulate(level, friction=F), FS)
        assert est.b == pytest.approx(B - F / level, rel=0.01)
        assert est.a == pytest.approx(A, rel=0.01)


def test_friction_fit_pooled_over_the_four_steps_recovers_a_b_and_the_coulomb_voltage():
    """η = −F·sign(u) is b·u_c·sign(θ̇) with u_c = F/b: pooled over the thesis's four step heights
    the fit returns a, b and u_c; from one step alone u_c is not identifiable (sign θ̇ ∝ u)."""
    F = 60.0
    runs = [simulate(level, friction=F) for level in (-12.0, -6.0, 6.0, 12.0)]
    est = identify_friction(runs, FS)
    assert est.a == pytest.approx(A, rel=0.01)
    assert est.b == pytest.approx(B, rel=0.01)
    assert est.coulomb == pytest.approx(F / B, rel=0.02)
    assert est.n_samples == 4 * (200 - 19)
    frictionless = identify_friction([simulate(level) for level in (-6.0, 12.0)], FS)
    assert abs(frictionless.coulomb) < 0.01 and frictionless.b == pytest.approx(B, rel=0.01)
    with pytest.raises(InvalidParameter, match="two heights"):
        identify_friction([simulate(6.0, friction=F)], FS)


def test_rejects_bad_input():
    theta, u = simulate(6.0)
    with pytest.raises(InvalidParameter):
        identify_signals(theta, u[:-1], FS)
    with pytest.raises(InvalidParameter):
        identify_signals(theta, np.zeros_like(u), FS)  # no excitation
    with pytest.raises(InvalidParameter):
        identify_signals(theta[:10], u[:10], FS)  # shorter than the window
    bad = theta.copy()
    bad[3] = np.nan
    with pytest.raises(InvalidParameter):
        identify_signals(bad, u, FS)


def test_identify_cli_bad_input(tmp_path, capsys):
    from labrunner.cli import main

    assert main(["identify", str(tmp_path / "missing.mcap")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["identify", str(tmp_path)]) == 2  # a directory without logs
    assert "no run logs" in capsys.readouterr().err
