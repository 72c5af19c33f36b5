"""Closed-form gain bounds (thesis section 2.4, appendix A, corrected) against the numerical
solver, and one test per error of the thesis, decided by the solver."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from labrunner.errors import InvalidParameter
from labrunner.stability import (
    abscissa_map,
    bounds,
    case_quasipolynomial,
    predict_stable,
    spectral_abscissa,
    stable_intervals,
)
from labrunner.stability.closed_forms import second_order_p_gain
from labrunner.stability.roots import first_order_crossing

A, B = 39.44, 108.55          # DC motor of the thesis: a [1/s], b [rad/(V s²)]
GAMMAS = (0.9 * B, B, 1.1 * B)
DELAYS = (0.01, 0.035, 0.05)
Z_TILDE = 2.028757838110434  # root of tan z = −z in (π/2, π)


def plant(case: str, gamma: float) -> dict:
    if case.endswith("ultralocal"):
        return {"gamma": gamma, "rho": B}
    if case == "mfc2-second-order":
        return {"gamma": gamma, "a0": 300.0, "a1": A, "b": B}
    return {"gamma": gamma, "a": A, "b": B}


def assert_same_interval(numeric, closed, rtol=1e-6):
    """Relative to max(|bound|, width): a bound of 0 (γ = b) is compared on the interval's scale."""
    assert numeric is not None and closed is not None
    scale = max(abs(closed[1] - closed[0]), 1e-300)
    for n, c in zip(numeric, closed):
        assert abs(n - c) <= rtol * max(abs(c), scale), (numeric, closed)


def alpha(case, **kw) -> float:
    return spectral_abscissa(case_quasipolynomial(case, **kw))


# --- closed forms against the solver -------------------------------------------------------------

@pytest.mark.parametrize("delay", DELAYS)
@pytest.mark.parametrize("gamma", GAMMAS)
@pytest.mark.parametrize("case", ["mfc1-ultralocal", "mfc1-motor", "mfc2-ultralocal", "mfc2-motor"])
def test_closed_forms_match_solver(case, gamma, delay):
    kw = plant(case, gamma)
    if case.startswith("mfc2"):
        k_d_range = bounds(case, delay=delay, k_d=0.0, **kw)["k_d"]
        result = bounds(case, delay=delay, k_d=0.3 * k_d_range[0] + 0.7 * k_d_range[1], numeric=True, **kw)
        assert_same_interval(result["numeric"]["k_d"], result["k_d"])
    else:
        result = bounds(case, delay=delay, numeric=True, **kw)
    assert_same_interval(result["numeric"]["k_p"], result["k_p"])


@pytest.mark.parametrize(("a0", "a1", "gamma", "delay"), [(300.0, A, B, 0.035), (2000.0, 0.0, 100.0, 0.05)])
def test_second_order_plant_a6_matches_solver(a0, a1, gamma, delay):
    # a₀δ² = 0.37 and 5: the second one has its k_d range cut by the root count, not by Condition 2
    kw = {"gamma": gamma, "delay": delay, "a0": a0, "a1": a1, "b": B}
    k_d_range = bounds("mfc2-second-order", k_d=0.0, **kw)["k_d"]
    result = bounds("mfc2-second-order", k_d=0.4 * k_d_range[0] + 0.6 * k_d_range[1], numeric=True, **kw)
    assert_same_interval(result["numeric"]["k_d"], result["k_d"])
    assert_same_interval(result["numeric"]["k_p"], result["k_p"])


def test_first_order_ultralocal_is_2_41():
    assert bounds("mfc1-ultralocal", gamma=2.0, delay=0.01, rho=3.0)["k_p"] == pytest.approx([0.0, np.pi / 2 * 2.0 / (3.0 * 0.01)])


@pytest.mark.parametrize("gamma", GAMMAS)
def test_motor_bound_is_2_46(gamma):
    delay = 0.035
    lo, hi = bounds("mfc1-motor", gamma=gamma, delay=delay, a=A, b=B)["k_p"]
    z = brentq(lambda z: np.tan(z) + z / (A * delay), np.pi / 2 + 1e-9, np.pi)
    assert lo == pytest.approx(A * (1 - gamma / B), abs=1e-12)
    assert hi == pytest.approx(A + gamma / (B * delay) * np.hypot(z, A * delay), rel=1e-12)


def test_z_tilde_is_2_0288_not_2_088():
    # thesis after (2.53) prints 2.088; appendix A.4 gives 2.0288, the root of tan z = −z in (π/2, π)
    z = first_order_crossing(1.0)
    assert z == pytest.approx(2.0288, abs=5e-5) and z == pytest.approx(Z_TILDE, rel=1e-14)
    assert np.tan(z) == pytest.approx(-z, rel=1e-12)
    assert abs(z - 2.088) > 0.05


# --- thesis errors -------------------------------------------------------------------------------

def test_printed_k_d_bound_2_53_leaves_an_unstable_gap():
    gamma, rho, delay = B, B, 0.035
    correct = bounds("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_d=1.0)["k_d"][1]
    printed = gamma / (delay * rho) * Z_TILDE * np.sin(Z_TILDE)       # (2.53)
    assert correct == pytest.approx(np.pi / 2 * gamma / (rho * delay), rel=1e-12) and printed > 1.15 * correct
    for k_d in np.linspace(correct, printed, 5)[1:-1]:
        assert bounds("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_d=k_d)["k_p"] is None
        scale = gamma / (rho * delay**2)
        assert stable_intervals(lambda kp: case_quasipolynomial("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay,
                                                                k_p=kp, k_d=k_d), -2 * scale, 40 * scale, n_scan=81) == []
    # the whole gap on a (k_d, k_p) map: not a single stable cell
    k_d = np.linspace(correct, printed, 12)[1:-1]
    k_p = np.linspace(0.0, 5 * gamma / (rho * delay**2), 30)
    m = abscissa_map(lambda kd, kp: case_quasipolynomial("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay,
                                                          k_p=kp, k_d=kd), k_d, k_p)
    assert np.all(m > 0)


@pytest.mark.parametrize("gamma", [0.9 * B, 1.1 * B])
def test_root_equation_of_2_59_has_the_ratio_inverted(gamma):
    delay, k_d = 0.035, 60.0
    result = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d, numeric=True)
    assert_same_interval(result["numeric"]["k_p"], result["k_p"])
    # as printed: (γ/b)(k_d − a) + a cos z = (z/δ) sin z, then (2.59)
    printed = second_order_p_gain(0.0, A * delay, gamma / B * (k_d - A) * delay)[1] * gamma / (B * delay**2)
    correct = result["k_p"][1]
    assert abs(printed - correct) > 0.01 * correct
    # the solver sides with the corrected bound between the two
    between = 0.5 * (printed + correct)
    assert (alpha("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d, k_p=between) < 0) == (between < correct)


def test_printed_and_corrected_2_59_agree_at_gamma_equal_b():
    delay, k_d = 0.035, 60.0
    printed = second_order_p_gain(0.0, A * delay, (k_d - A) * delay)[1] / delay**2
    assert bounds("mfc2-motor", gamma=B, delay=delay, a=A, b=B, k_d=k_d)["k_p"][1] == pytest.approx(printed, rel=1e-13)


@pytest.mark.parametrize(("gamma", "quoted"), [(1.1 * B, -3.54), (0.9 * B, 4.33)])
def test_quoted_k_d_min_values_are_wrong(gamma, quoted):
    delay = 0.035
    result = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=0.0, numeric=True)
    assert result["k_d"][0] == pytest.approx(A * (1 - gamma / B), rel=1e-12)       # ±3.944, not the quoted
    assert result["numeric"]["k_d"][0] == pytest.approx(A * (1 - gamma / B), rel=1e-6)
    # between the true k_d,min and the quoted one a stable k_p exists (γ = 1.1b), or not (γ = 0.9b)
    k_d = 0.5 * (quoted + A * (1 - gamma / B))
    k_p = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d)["k_p"]
    if k_d > A * (1 - gamma / B):
        assert alpha("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d, k_p=np.mean(k_p)) < 0
    else:
        assert k_p is None
        assert stable_intervals(lambda kp: case_quasipolynomial("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B,
                                                                k_p=kp, k_d=k_d), -100.0, 5000.0, n_scan=61) == []


def test_tangency_bound_of_a6_leaves_an_unstable_gap():
    # A.6 bounds κ_d by the tangency tan z = −(z/δ − δa₀/z)/(1/δ + δa₀/z² + a₁), like (2.53)
    a0, a1, gamma, delay = 300.0, 5.0, B, 0.035
    def tangency(z):
        return (1 / delay + delay * a0 / z**2 + a1) * np.sin(z) + (z / delay - delay * a0 / z) * np.cos(z)
    z = brentq(tangency, np.pi / 2, 3 * np.pi / 2)
    kappa = (z / delay - delay * a0 / z) * np.sin(z) - a1 * np.cos(z)
    printed = gamma / B * kappa + a1
    kw = {"gamma": gamma, "delay": delay, "a0": a0, "a1": a1, "b": B}
    correct = bounds("mfc2-second-order", k_d=0.0, **kw)["k_d"][1]
    assert printed > 1.05 * correct
    k_d = 0.5 * (correct + printed)
    assert bounds("mfc2-second-order", k_d=k_d, **kw)["k_p"] is None
    assert stable_intervals(lambda kp: case_quasipolynomial("mfc2-second-order", k_p=kp, k_d=k_d, **kw),
                            -500.0, 20000.0, n_scan=81) == []


def test_condition_2_of_a6_is_not_sufficient_for_k_d():
    # A.6: κ_d > −a₁ − δa₀ from Condition 2 alone; with a₀δ² = 5 Δ_Im loses real roots first
    a0, gamma, delay = 2000.0, 100.0, 0.05
    kw = {"gamma": gamma, "delay": delay, "a0": a0, "a1": 0.0, "b": B}
    printed = gamma / B * (-delay * a0)                   # k_d = a₁ + (γ/b) κ_d,min
    correct = bounds("mfc2-second-order", k_d=0.0, **kw)["k_d"][0]
    assert correct > printed + 20.0
    k_d = 0.5 * (printed + correct)
    assert bounds("mfc2-second-order", k_d=k_d, **kw)["k_p"] is None
    assert stable_intervals(lambda kp: case_quasipolynomial("mfc2-second-order", k_p=kp, k_d=k_d, **kw),
                            -200.0, 20000.0, n_scan=81) == []


def test_unstable_plant_second_order_matches_solver():
    # remark 2.8 carried over to (2.57): a < 0, aδ = −0.7
    k_d_range = bounds("mfc2-motor", gamma=B, delay=0.035, a=-20.0, b=B, k_d=0.0)["k_d"]
    assert k_d_range[0] == pytest.approx(-20.0 * (1 - 1.0), abs=1e-12)   # a(1 − γ/b) = 0 at γ = b
    result = bounds("mfc2-motor", gamma=B, delay=0.035, a=-20.0, b=B, k_d=np.mean(k_d_range), numeric=True)
    assert_same_interval(result["numeric"]["k_d"], result["k_d"])
    assert_same_interval(result["numeric"]["k_p"], result["k_p"])


def test_remark_2_8_needs_a_delta_above_minus_one():
    # unstable plant a < 0: the bound holds for aδ > −1 only; beyond it no gain is stable
    ok = bounds("mfc1-motor", gamma=B, delay=0.035, a=-20.0, b=B, numeric=True)
    assert_same_interval(ok["numeric"]["k_p"], ok["k_p"])
    z = brentq(lambda z: np.tan(z) + z / (-20.0 * 0.035), 1e-6, np.pi / 2 - 1e-9)   # z̃ ∈ (0, π/2)
    assert ok["k_p"][1] == pytest.approx(-20.0 + 1 / 0.035 * np.hypot(z, 20.0 * 0.035), rel=1e-12)
    none = bounds("mfc1-motor", gamma=B, delay=0.035, a=-40.0, b=B, numeric=True)   # aδ = −1.4
    assert none["k_p"] is None and none["numeric"]["k_p"] is None


# --- neutral equation (A.11) ---------------------------------------------------------------------

def test_neutral_equals_retarded_at_gamma_b():
    kw = {"gamma": B, "delay": 0.035, "a": A, "b": B, "k_p": 50.0}
    assert alpha("mfc1-motor", neutral=True, **kw) == pytest.approx(alpha("mfc1-motor", **kw), rel=1e-12)


def test_neutral_is_unstable_for_gamma_below_half_b():
    # B = (γ − b)/γ, |B| > 1 for γ < b/2: the root chain sits at ln|B|/δ > 0 for every k_p
    for k_p in (1.0, 20.0, 60.0):
        value = alpha("mfc1-motor", neutral=True, gamma=0.4 * B, delay=0.035, a=A, b=B, k_p=k_p)
        assert value >= np.log(1.5) / 0.035 - 1e-9


def test_neutral_and_retarded_agree_near_gamma_b():
    lo, hi = bounds("mfc1-motor", gamma=1.1 * B, delay=0.035, a=A, b=B)["k_p"]
    for k_p in (lo + 0.1 * (hi - lo), 0.5 * (lo + hi)):
        assert alpha("mfc1-motor", neutral=True, gamma=1.1 * B, delay=0.035, a=A, b=B, k_p=k_p) < 0


# --- predict_stable and validation ---------------------------------------------------------------

def test_predict_stable_matches_a_solver_map():
    delay = 0.035
    gamma = np.linspace(0.5 * B, 1.5 * B, 9)
    k_p = np.linspace(-10.0, 160.0, 13)
    pred = predict_stable("mfc1-motor", gamma=gamma[:, None], k_p=k_p[None, :], delay=delay, a=A, b=B)
    m = abscissa_map(lambda kp, g: case_quasipolynomial("mfc1-motor", gamma=g, k_p=kp, delay=delay, a=A, b=B), k_p, gamma)
    assert pred.shape == (9, 13) and pred.dtype == bool
    np.testing.assert_array_equal(pred, m < 0)
    assert pred.any() and not pred.all()


def test_predict_stable_second_order_and_scalar():
    kw = {"gamma": B, "delay": 0.035, "rho": B}
    assert predict_stable("mfc2-ultralocal", k_p=100.0, k_d=20.0, **kw) is True
    assert predict_stable("mfc2-ultralocal", k_p=100.0, k_d=46.0, **kw) is False   # in the (2.53) gap
    out = predict_stable("mfc2-ultralocal", k_p=np.array([100.0, -1.0, 100.0]), k_d=np.array([20.0, 20.0, 60.0]), **kw)
    np.testing.assert_array_equal(out, [True, False, False])


@pytest.mark.parametrize(
    ("case", "kw", "field"),
    [("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.0, "rho": 1.0}, "delay"),
     ("mfc1-ultralocal", {"gamma": -1.0, "delay": 0.1, "rho": 1.0}, "gamma"),
     ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.1, "rho": 0.0}, "rho"),
     ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.1}, "rho"),
     ("mfc1-motor", {"gamma": 1.0, "delay": 0.1, "b": 1.0}, "a"),
     ("mfc1-motor", {"gamma": float("nan"), "delay": 0.1, "a": 1.0, "b": 1.0}, "gamma"),
     ("mfc1-motor", {"gamma": 1.0, "delay": 0.1, "a": 1.0, "b": 1.0, "k_d": 3.0}, "k_d"),
     ("mfc2-motor", {"gamma": 1.0, "delay": 0.1, "a": 1.0, "b": 1.0}, "k_d"),
     ("mfc2-second-order", {"gamma": 1.0, "delay": 0.1, "a0": -1.0, "a1": 1.0, "b": 1.0, "k_d": 1.0}, "a0"),
     ("mfc3", {"gamma": 1.0, "delay": 0.1}, "case")],
)
def test_bad_input(case, kw, field):
    with pytest.raises(InvalidParameter) as err:
        bounds(case, **kw)
    assert err.value.field == field


def test_rho_defaults_to_b():
    assert bounds("mfc1-ultralocal", gamma=2.0, delay=0.01, b=3.0) == bounds("mfc1-ultralocal", gamma=2.0, delay=0.01, rho=3.0)
