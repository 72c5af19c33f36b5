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
from labrunner.stability.roots import ascending_roots, first_order_crossing

A, B = 39.44, 108.55  # DC motor of the thesis: a [1/s], b [rad/(V s²)]
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


def roots_on_grid(h, z_max: float, step: float = 1e-3) -> np.ndarray:
    """Positive roots of h on (0, z_max] from sign changes on a fine grid (no turning points),
    independent of labrunner.stability.roots."""
    z = np.arange(step, z_max, step)
    v = h(z)
    return np.array([brentq(h, z[i], z[i + 1], xtol=1e-15) for i in np.flatnonzero(np.sign(v[:-1]) != np.sign(v[1:]))])


def tilde_z(a_delta: float) -> float:
    """z̃ ∈ (π/2, π) with tan z̃ = −z̃/(aδ) (thesis (2.46), (2.58))."""
    return brentq(lambda z: np.tan(z) + z / a_delta, np.pi / 2 + 1e-12, np.pi)


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
    assert bounds("mfc1-ultralocal", gamma=2.0, delay=0.01, rho=3.0)["k_p"] == pytest.approx(
        [0.0, np.pi / 2 * 2.0 / (3.0 * 0.01)]
    )


@pytest.mark.parametrize("gamma", GAMMAS)
def test_motor_bound_is_2_46(gamma):
    delay = 0.035
    lo, hi = bounds("mfc1-motor", gamma=gamma, delay=delay, a=A, b=B)["k_p"]
    z = brentq(lambda z: np.tan(z) + z / (A * delay), np.pi / 2 + 1e-9, np.pi)
    assert lo == pytest.approx(A * (1 - gamma / B), abs=1e-12)
    assert hi == pytest.approx(A + gamma / (B * delay) * np.hypot(z, A * delay), rel=1e-12)


@pytest.mark.parametrize("d", [0.1, 0.5, 1.0, 1.5, 1.56])
def test_ultralocal_k_p_bound_is_2_54(d):
    """(2.54): 0 < k_p < min_{j odd} (γ/(ρδ²)) z_j² cos z_j, z_j the ascending roots of
    ρ k_d / sin z = (γ/δ) z, i.e. z sin z = ρ k_d δ/γ = d, for k_d below the corrected bound."""
    gamma, rho, delay = 0.9 * B, B, 0.035
    k_d = d * gamma / (rho * delay)
    z = roots_on_grid(lambda z: z * np.sin(z) - d, 30 * np.pi)
    assert z.size % 2 == 0 and z[0] < np.pi / 2 < z[1] < np.pi  # z_1, z_2 in (0, π): real roots
    expected = np.min(gamma / (rho * delay**2) * z[0::2] ** 2 * np.cos(z[0::2]))
    lo, hi = bounds("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_d=k_d)["k_p"]
    assert lo == 0.0 and hi == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("delay", DELAYS)
@pytest.mark.parametrize("gamma", GAMMAS)
def test_motor_k_d_interval_is_2_58_as_printed(gamma, delay):
    """(2.58): a(1 − γ/b) < k_d < a + γ/(bδ)·sqrt(z̃² + (aδ)²), tan z̃ = −z̃/(aδ) in (π/2, π)."""
    lo, hi = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=0.0)["k_d"]
    assert lo == pytest.approx(A * (1 - gamma / B), rel=1e-12, abs=1e-12)
    assert hi == pytest.approx(A + gamma / (B * delay) * np.hypot(tilde_z(A * delay), A * delay), rel=1e-12)


@pytest.mark.parametrize(("gamma", "k_d"), [(0.9 * B, 60.0), (B, 20.0), (1.1 * B, 5.0), (1.1 * B, 100.0)])
def test_motor_k_p_bound_is_2_59_with_the_corrected_root_equation(gamma, k_d):
    """(2.59): 0 < k_p < min_{j odd} (aγ z_j/(bδ))(sin z_j + z_j/(aδ) cos z_j), z_j the ascending roots
    of (b/γ)(k_d − a) + a cos z = (z/δ) sin z (Farkh et al. 2009 with K = b/γ, as appendix A.5 maps it)."""
    delay = 0.035
    z = roots_on_grid(lambda z: B / gamma * (k_d - A) + A * np.cos(z) - z / delay * np.sin(z), 30 * np.pi)
    zo = z[0::2]
    expected = np.min(A * gamma * zo / (B * delay) * (np.sin(zo) + zo / (A * delay) * np.cos(zo)))
    lo, hi = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d)["k_p"]
    assert lo == 0.0 and hi == pytest.approx(expected, rel=1e-12)


def test_roots_ascend_between_turning_points_from_z1():
    """Every positive root of z sin z − D, ascending, the first one z_1 (z_0 = 0 is not listed),
    equal to a brute-force grid search; likewise the roots of (2.59)'s corrected equation."""
    for d in (0.3, 1.2, 1.8):
        got = ascending_roots(lambda z: z * np.sin(z) - d, lambda z: np.sin(z) + z * np.cos(z), 12 * np.pi)
        ref = roots_on_grid(lambda z: z * np.sin(z) - d, 12 * np.pi)
        assert got.size == ref.size and np.all(np.diff(got) > 0) and got[0] > 0
        np.testing.assert_allclose(got, ref, rtol=1e-13)
    h = lambda z: 2.0 + 1.4 * np.cos(z) - z * np.sin(z)  # noqa: E731
    dh = lambda z: -1.4 * np.sin(z) - np.sin(z) - z * np.cos(z)  # noqa: E731
    np.testing.assert_allclose(ascending_roots(h, dh, 12 * np.pi), roots_on_grid(h, 12 * np.pi), rtol=1e-13)


@pytest.mark.parametrize("a_delta", [0.01, 0.4, 1.0, 1.38, 25.0, -0.3, -0.9])
def test_first_order_crossing_solves_tan_z(a_delta):
    """z̃ of tan z = −z/(aδ): in (π/2, π) for aδ > 0, in (0, π/2) for −1 < aδ < 0 (remark 2.8)."""
    z = first_order_crossing(a_delta)
    lo, hi = (np.pi / 2 + 1e-12, np.pi) if a_delta > 0 else (1e-9, np.pi / 2 - 1e-12)
    assert z == pytest.approx(brentq(lambda x: np.tan(x) + x / a_delta, lo, hi, xtol=1e-15), rel=1e-13)
    assert first_order_crossing(0.0) == pytest.approx(np.pi / 2, rel=1e-14)
    assert first_order_crossing(-1.0) is None


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
    printed = gamma / (delay * rho) * Z_TILDE * np.sin(Z_TILDE)  # (2.53)
    assert correct == pytest.approx(np.pi / 2 * gamma / (rho * delay), rel=1e-12) and printed > 1.15 * correct
    for k_d in np.linspace(correct, printed, 5)[1:-1]:
        assert bounds("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_d=k_d)["k_p"] is None
        scale = gamma / (rho * delay**2)
        assert (
            stable_intervals(
                lambda kp: case_quasipolynomial("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_p=kp, k_d=k_d),
                -2 * scale,
                40 * scale,
                n_scan=81,
            )
            == []
        )
    # the whole gap on a (k_d, k_p) map: not a single stable cell
    k_d = np.linspace(correct, printed, 12)[1:-1]
    k_p = np.linspace(0.0, 5 * gamma / (rho * delay**2), 30)
    m = abscissa_map(
        lambda kd, kp: case_quasipolynomial("mfc2-ultralocal", gamma=gamma, rho=rho, delay=delay, k_p=kp, k_d=kd),
        k_d,
        k_p,
    )
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
    assert result["k_d"][0] == pytest.approx(A * (1 - gamma / B), rel=1e-12)  # ±3.944, not the quoted
    assert result["numeric"]["k_d"][0] == pytest.approx(A * (1 - gamma / B), rel=1e-6)
    # between the true k_d,min and the quoted one a stable k_p exists (γ = 1.1b), or not (γ = 0.9b)
    k_d = 0.5 * (quoted + A * (1 - gamma / B))
    k_p = bounds("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d)["k_p"]
    if k_d > A * (1 - gamma / B):
        assert alpha("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_d=k_d, k_p=np.mean(k_p)) < 0
    else:
        assert k_p is None
        assert (
            stable_intervals(
                lambda kp: case_quasipolynomial("mfc2-motor", gamma=gamma, delay=delay, a=A, b=B, k_p=kp, k_d=k_d),
                -100.0,
                5000.0,
                n_scan=61,
            )
            == []
        )


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
    assert (
        stable_intervals(
            lambda kp: case_quasipolynomial("mfc2-second-order", k_p=kp, k_d=k_d, **kw), -500.0, 20000.0, n_scan=81
        )
        == []
    )


def test_condition_2_of_a6_is_not_sufficient_for_k_d():
    # A.6: κ_d > −a₁ − δa₀ from Condition 2 alone; with a₀δ² = 5 Δ_Im loses real roots first
    a0, gamma, delay = 2000.0, 100.0, 0.05
    kw = {"gamma": gamma, "delay": delay, "a0": a0, "a1": 0.0, "b": B}
    printed = gamma / B * (-delay * a0)  # k_d = a₁ + (γ/b) κ_d,min
    correct = bounds("mfc2-second-order", k_d=0.0, **kw)["k_d"][0]
    assert correct > printed + 20.0
    k_d = 0.5 * (printed + correct)
    assert bounds("mfc2-second-order", k_d=k_d, **kw)["k_p"] is None
    assert (
        stable_intervals(
            lambda kp: case_quasipolynomial("mfc2-second-order", k_p=kp, k_d=k_d, **kw), -200.0, 20000.0, n_scan=81
        )
        == []
    )


def test_unstable_plant_second_order_matches_solver():
    # remark 2.8 carried over to (2.57): a < 0, aδ = −0.7
    k_d_range = bounds("mfc2-motor", gamma=B, delay=0.035, a=-20.0, b=B, k_d=0.0)["k_d"]
    assert k_d_range[0] == pytest.approx(-20.0 * (1 - 1.0), abs=1e-12)  # a(1 − γ/b) = 0 at γ = b
    result = bounds("mfc2-motor", gamma=B, delay=0.035, a=-20.0, b=B, k_d=np.mean(k_d_range), numeric=True)
    assert_same_interval(result["numeric"]["k_d"], result["k_d"])
    assert_same_interval(result["numeric"]["k_p"], result["k_p"])


def test_remark_2_8_needs_a_delta_above_minus_one():
    # unstable plant a < 0: the bound holds for aδ > −1 only; beyond it no gain is stable
    ok = bounds("mfc1-motor", gamma=B, delay=0.035, a=-20.0, b=B, numeric=True)
    assert_same_interval(ok["numeric"]["k_p"], ok["k_p"])
    z = brentq(lambda z: np.tan(z) + z / (-20.0 * 0.035), 1e-6, np.pi / 2 - 1e-9)  # z̃ ∈ (0, π/2)
    assert ok["k_p"][1] == pytest.approx(-20.0 + 1 / 0.035 * np.hypot(z, 20.0 * 0.035), rel=1e-12)
    none = bounds("mfc1-motor", gamma=B, delay=0.035, a=-40.0, b=B, numeric=True)  # aδ = −1.4
    assert none["k_p"] is None and none["numeric"]["k_p"] is None


# --- neutral equation (A.11) ---------------------------------------------------------------------


@pytest.mark.parametrize("gamma", [0.4 * B, 0.9 * B, 1.3 * B])
def test_neutral_quasipolynomial_is_a11(gamma):
    """(A.11) written out: ė − ((γ−b)/γ)ė(t−δ) + a e + (b/γ)(k_p − a)e(t−δ) − ((γ−b)a/γ)e(t−δ) = 0."""
    delay, k_p = 0.035, 37.0
    qp = case_quasipolynomial("mfc1-motor", gamma=gamma, delay=delay, a=A, b=B, k_p=k_p, neutral=True)
    assert qp.is_neutral
    s = np.array([0.3 + 2.0j, -40.0 + 150.0j, 12.0 - 7.0j])
    e = np.exp(-s * delay)
    expected = s - (gamma - B) / gamma * s * e + A + B / gamma * (k_p - A) * e - (gamma - B) * A / gamma * e
    np.testing.assert_allclose(qp.evaluate(s)[0], expected, rtol=1e-13)


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
    m = abscissa_map(
        lambda kp, g: case_quasipolynomial("mfc1-motor", gamma=g, k_p=kp, delay=delay, a=A, b=B), k_p, gamma
    )
    assert pred.shape == (9, 13) and pred.dtype == bool
    np.testing.assert_array_equal(pred, m < 0)
    assert pred.any() and not pred.all()


def test_predict_stable_second_order_and_scalar():
    kw = {"gamma": B, "delay": 0.035, "rho": B}
    assert predict_stable("mfc2-ultralocal", k_p=100.0, k_d=20.0, **kw) is True
    assert predict_stable("mfc2-ultralocal", k_p=100.0, k_d=46.0, **kw) is False  # in the (2.53) gap
    out = predict_stable("mfc2-ultralocal", k_p=np.array([100.0, -1.0, 100.0]), k_d=np.array([20.0, 20.0, 60.0]), **kw)
    np.testing.assert_array_equal(out, [True, False, False])


@pytest.mark.parametrize(
    ("case", "kw", "field"),
    [
        ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.0, "rho": 1.0}, "delay"),
        ("mfc1-ultralocal", {"gamma": -1.0, "delay": 0.1, "rho": 1.0}, "gamma"),
        ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.1, "rho": 0.0}, "rho"),
        ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.1}, "rho"),
        ("mfc1-ultralocal", {"gamma": 1.0, "delay": 0.1, "b": -1.0}, "b"),  # rho defaults to b: b is named
        ("mfc1-motor", {"gamma": 1.0, "delay": 0.1, "b": 1.0}, "a"),
        ("mfc1-motor", {"gamma": float("nan"), "delay": 0.1, "a": 1.0, "b": 1.0}, "gamma"),
        ("mfc1-motor", {"gamma": 1.0, "delay": 0.1, "a": 1.0, "b": 1.0, "k_d": 3.0}, "k_d"),
        ("mfc2-motor", {"gamma": 1.0, "delay": 0.1, "a": 1.0, "b": 1.0}, "k_d"),
        ("mfc2-second-order", {"gamma": 1.0, "delay": 0.1, "a0": -1.0, "a1": 1.0, "b": 1.0, "k_d": 1.0}, "a0"),
        ("mfc3", {"gamma": 1.0, "delay": 0.1}, "case"),
    ],
)
def test_bad_input(case, kw, field):
    with pytest.raises(InvalidParameter) as err:
        bounds(case, **kw)
    assert err.value.field == field


def test_rho_defaults_to_b():
    assert bounds("mfc1-ultralocal", gamma=2.0, delay=0.01, b=3.0) == bounds(
        "mfc1-ultralocal", gamma=2.0, delay=0.01, rho=3.0
    )


def test_cached_closed_forms_equal_a_fresh_evaluation():
    """first_order_gain and second_order_p_gain are cached; the cache returns what the formula gives."""
    from labrunner.stability.closed_forms import first_order_gain

    for a_delta in (-0.5, 0.0, 1.3804, 7.0):
        assert first_order_gain(a_delta) == first_order_gain.__wrapped__(a_delta)
    for d in (-1.0, 0.3, 1.2, 1.8):
        assert second_order_p_gain(0.0, 1.38, d) == second_order_p_gain.__wrapped__(0.0, 1.38, d)


def test_the_scalar_crossing_d_of_brents_steps_is_the_vectorised_one_bit_for_bit():
    """closed_forms._crossing_d_at (Brent's steps, on floats) and crossing_d (numpy, np.sinc) give the same
    float at every z, 0 and tiny ones included: the bounds do not depend on which one found the root. It
    assumes numpy's float64 sin/cos are libm's (math.sin/cos), as on this project's machines; a numpy whose
    SIMD sin differs by an ulp would fail it here, not in the bounds."""
    from labrunner.stability.closed_forms import _crossing_d_at, crossing_d

    rng = np.random.default_rng(11)
    zs = [0.0, 1e-300, 5e-324, 1e-9, np.pi, 2 * np.pi, *rng.uniform(0.0, 150.0, 3000), *rng.uniform(-5, 5, 500)]
    for a0, a1 in [(0.0, 0.0), (0.0, 0.3), (1.7, -0.4), (*rng.uniform(0.0, 6.0, 1), *rng.uniform(-1.0, 2.0, 1))]:
        want = crossing_d(np.array(zs), a0, a1)
        got = [_crossing_d_at(float(z), a0, a1) for z in zs]
        assert [float(w) for w in want] == got, (a0, a1)
        assert all(float(crossing_d(np.array(z), a0, a1)) == g for z, g in zip(zs[:50], got[:50]))
