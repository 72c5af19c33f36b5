"""labrunner.differentiators: design, kernels and weights against the thesis and the papers.

References: thesis Sec. 2.1 and Sec. 3 (safety routine, line ~927 of the seed text), valve paper
(paper 1) Table 1, plate paper (paper 2) appendix B (B.8)-(B.11), and closed-form identities.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import quad

from labrunner.differentiators import METHODS, Differentiator, design
from labrunner.differentiators.design import whole_samples
from labrunner.errors import InvalidParameter


def gauss_integral(f, a: float, b: float, nodes: int = 60) -> float:
    """∫_a^b f by Gauss–Legendre (exact for polynomials of degree < 2·nodes)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    t = (b - a) / 2 * x + (a + b) / 2
    return float((b - a) / 2 * np.dot(w, f(t)))


# --- the papers' numbers --------------------------------------------------------------------------


def test_thesis_delay_35ms_for_alpha_beta_9_at_200hz():
    """Thesis: N = 0, α = β = 9, ω_c = 200 rad/s, f_s = 200 Hz → δ_t = 35 ms."""
    d = design(alpha=9, beta=9, omega_c=200, fs=200)
    assert d.n_s == 14
    assert d.delay_s == pytest.approx(0.035, abs=1e-15)
    assert d.discrete_delay_s(1) == pytest.approx(0.035 - 0.0025, abs=1e-15)


def test_thesis_safety_estimator_window_is_9_samples():
    """Thesis Sec. 3 (safety routine): α = β = 6, ω_c = 200 rad/s, N = 0, f_s = 200 Hz → n_s = 9."""
    d = design(alpha=6, beta=6, omega_c=200, fs=200)
    assert d.n_s == 9 and isinstance(d.n_s, int)
    assert d.weights(1).shape == (9,)


# Valve paper Table 1 (f_s = 4 kHz): (α = β, ω_c [rad/s], δ [ms] as printed, T·f_s).
VALVE_TABLE_1 = [
    (2, 250, 7.75, 62),
    (2, 450, 4.25, 34),
    (4, 850, 4.0, 32),
    (3, 450, 5.875, 47),
    (2, 150, 13.0, 104),
    (8, 250, 23.375, 203),
]


@pytest.mark.parametrize("alpha, omega_c, delay_ms, n_s", VALVE_TABLE_1)
def test_valve_table_1_windows(alpha, omega_c, delay_ms, n_s):
    d = design(alpha=alpha, beta=alpha, omega_c=omega_c, fs=4000)
    assert d.n_s == n_s
    assert d.window_s == n_s / 4000


@pytest.mark.parametrize("alpha, omega_c, delay_ms, n_s", VALVE_TABLE_1[:5])
def test_valve_table_1_delays(alpha, omega_c, delay_ms, n_s):
    """α = β, N = 0: δ = T/2 (paper 1, Sec. 5.1), as printed for No. 1-5."""
    assert design(alpha=alpha, beta=alpha, omega_c=omega_c, fs=4000).delay_s * 1e3 == pytest.approx(delay_ms)


def test_valve_table_1_no_6_delay_is_the_inconsistent_one():
    """No. 6 prints δ = 23.375 ms, but its own window T·f_s = 203 gives T/2 = 203/8000 s = 25.375 ms
    (23.375 ms would need T·f_s = 187, which ω_c = 250 rad/s does not give)."""
    d = design(alpha=8, beta=8, omega_c=250, fs=4000)
    assert d.n_s == 203
    assert d.delay_s * 1e3 == pytest.approx(25.375, abs=1e-12)
    assert d.delay_s * 1e3 != pytest.approx(23.375, abs=0.5)


def test_cutoff_rule_n0_closed_form():
    """Othmane et al. (2022, Sec. 4.2.2), N = 0: ω_c·T = (Γ(2μ+κ)/Γ(μ+κ))^(1/μ), μ = 1 + min(α, β)."""
    for alpha, beta in [(1, 1), (2.5, 7), (9, 3), (30, 30)]:
        mu, kappa = 1 + min(alpha, beta), abs(alpha - beta)
        k_c = (math.gamma(2 * mu + kappa) / math.gamma(mu + kappa)) ** (1 / mu)
        d = design(alpha=alpha, beta=beta, window=0.5, fs=1000)
        assert d.omega_c_actual * d.window_s == pytest.approx(k_c, rel=1e-13)


def test_delay_formulas():
    """Thesis (2.3): (α+1)/(α+β+2)·T for N = 0, (1−ϑ)T/2 otherwise."""
    d = design(alpha=2, beta=5, window=0.1, fs=1000)
    assert d.delay_s == pytest.approx(3 / 9 * 0.1)
    d = design(alpha=2, beta=5, window=0.1, fs=1000, N=1, theta=0.4)
    assert d.delay_s == pytest.approx(0.3 * 0.1)
    assert design(alpha=2, beta=2, window=0.1, fs=1000, N=2, theta=1.0).delay_s == 0.0  # delay-free


def test_default_theta_is_largest_root_of_next_jacobi_polynomial():
    """N = 1, α = β = 1: P_2^{(1,1)} ∝ 5ν² − 1 has largest root 1/√5."""
    d = design(alpha=1, beta=1, window=0.1, fs=1000, N=1)
    assert d.theta == pytest.approx(1 / math.sqrt(5), rel=1e-13)


# --- kernels: thesis Sec. 2.3 / paper 2 appendix B -----------------------------------------------------


def test_kernel_alpha_beta_1():
    """N = 0, α = β = 1: g = 3!/T³·τ(T−τ), g' = 3!/T³·(T−2τ) on [0, T], 0 outside."""
    d = design(alpha=1, beta=1, window=0.2, fs=100)
    T = d.window_s
    tau = np.linspace(0, T, 41)
    np.testing.assert_allclose(d.kernel(0, tau), 6 / T**3 * tau * (T - tau), rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(d.kernel(1, tau), 6 / T**3 * (T - 2 * tau), rtol=1e-13)
    assert np.all(d.kernel(0, np.array([-0.01, T + 0.01])) == 0.0)


def test_kernel_alpha_beta_2_second_derivative_b10():
    """Paper 2 (B.9)/(B.10): α = β = 2: g = 5!/(2!2!T⁵)τ²(T−τ)², g'' = 5!/(2T⁵)(6τ² − 6Tτ + T²)."""
    d = design(alpha=2, beta=2, window=0.05, fs=1000)
    T = d.window_s
    tau = np.linspace(0, T, 51)
    np.testing.assert_allclose(d.kernel(0, tau), 120 / (4 * T**5) * tau**2 * (T - tau) ** 2, rtol=1e-12, atol=1e-9)
    expected = 120 / (2 * T**5) * (6 * tau**2 - 6 * T * tau + T**2)
    np.testing.assert_allclose(d.kernel(2, tau), expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("alpha, beta", [(3, 5), (0.5, 2.25), (120, 80)])
def test_kernel_n0_is_b8_in_closed_form(alpha, beta):
    """Paper 2 (B.8) with the factorial restored (SEED-NOTES): g = (α+β+1)!/(α!β!T^{α+β+1})·τ^α(T−τ)^β,
    compared in log space so that α = 120 is checked too."""
    d = design(alpha=alpha, beta=beta, window=0.3, fs=1000)
    T = d.window_s
    tau = np.linspace(0.05, 0.95, 19) * T
    log_g = (
        math.lgamma(alpha + beta + 2)
        - math.lgamma(alpha + 1)
        - math.lgamma(beta + 1)
        + alpha * np.log(tau)
        + beta * np.log(T - tau)
        - (alpha + beta + 1) * math.log(T)
    )
    np.testing.assert_allclose(d.kernel(0, tau), np.exp(log_g), rtol=1e-10)


def test_kernel_integrates_to_one_and_first_moment_is_the_delay():
    for N, theta in [(0, None), (1, None), (2, 0.3)]:
        d = design(alpha=2.5, beta=4, window=0.1, fs=1000, N=N, theta=theta)
        T = d.window_s
        assert gauss_integral(lambda t: d.kernel(0, t), 0, T, 200) == pytest.approx(1, rel=1e-10)
        # x(t) = t: ∫ g(τ)(t−τ)dτ = t − δ_t
        assert gauss_integral(lambda t: d.kernel(0, t) * t, 0, T, 200) == pytest.approx(d.delay_s, rel=1e-9)


def test_b3_exactness_of_the_second_derivative_estimate():
    """Paper 2 B.3: for ÿ = F, y = F t²/2, ∫ g''(t−τ) y(τ) dτ over the window equals F exactly.
    Checked for the continuous kernel (exact Gauss quadrature) and the analytic discretisation."""
    F = 3.7
    d = design(alpha=2, beta=2, window=0.08, fs=1000, method="analytic")
    T = d.window_s
    for t in (0.0, 0.31, 2.0):
        est = gauss_integral(lambda tau: d.kernel(2, t - tau) * F * tau**2 / 2, t - T, t, 10)
        assert est == pytest.approx(F, rel=1e-9)  # cancellation of ~1e7-sized terms at t = 2 s
    k = np.arange(200, 260)
    w = d.weights(2)
    y = F * (np.arange(300) / d.fs) ** 2 / 2
    est = np.array([np.dot(w, y[kk - np.arange(w.size)]) for kk in k])
    np.testing.assert_allclose(est, F, rtol=1e-8)


# --- weights -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_weights_normalisation_phi(method):
    """Thesis (2.4): with Φ_n = t_sⁿ/n!·Σ w_n[j](−j)ⁿ, the normalised weights satisfy Σ w[j](−j t_s)ⁿ/n! = 1."""
    d = design(alpha=3.5, beta=2.5, omega_c=80, fs=500, method=method)
    for n in range(3):
        w = d.weights(n)
        j = np.arange(w.size)
        assert np.dot(w, (-j / d.fs) ** n) / math.factorial(n) == pytest.approx(1.0, rel=1e-12)
    assert d.weights(0).size == (d.n_s + 1 if method == "trapezoidal" else d.n_s)


def test_midpoint_weights_are_kernel_at_midpoints():
    """Thesis Sec. 2.1: mid-point rule, θ = 1/2, L = n_s, w_n[j] = t_s g⁽ⁿ⁾[j + 1/2] (before 1/Φ_n)."""
    d = design(alpha=4, beta=6, omega_c=120, fs=1000)
    raw = d.kernel(1, (np.arange(d.n_s) + 0.5) / d.fs) / d.fs
    phi = np.dot(raw, -np.arange(d.n_s) / d.fs)
    np.testing.assert_allclose(d.weights(1), raw / phi, rtol=1e-13)


def test_analytic_weights_are_exact_interval_integrals():
    d = design(alpha=1.5, beta=3, window=0.012, fs=1000, method="analytic")

    def g1(t: float) -> float:
        return float(d.kernel(1, np.array([t]))[0])

    raw = np.array([quad(g1, j / d.fs, (j + 1) / d.fs, epsabs=0, epsrel=1e-13)[0] for j in range(d.n_s)])
    phi = np.dot(raw, -np.arange(d.n_s) / d.fs)
    np.testing.assert_allclose(d.weights(1), raw / phi, rtol=1e-10)


def test_symmetric_midpoint_estimate_exact_for_quadratics():
    """α = β, N = 0 (degree of exactness n + 1): the discrete first derivative of t² is exactly
    2(t − discrete delay), the alignment that estimate() and StreamingFIR promise."""
    d = design(alpha=5, beta=5, omega_c=60, fs=1000)
    w = d.weights(1)
    k = np.arange(d.n_s, d.n_s + 40)
    t = np.arange(k[-1] + 1) / d.fs
    est = np.array([np.dot(w, t[kk - np.arange(w.size)] ** 2) for kk in k])
    np.testing.assert_allclose(est, 2 * (t[k] - d.discrete_delay_s(1)), rtol=1e-11)


def test_large_alpha_with_log_gamma():
    """α = β = 150 (AlgDiff overflows from α ≈ 100): finite, normalised, odd first-derivative weights."""
    d = design(alpha=150, beta=150, omega_c=100, fs=1000)
    for n in range(3):
        w = d.weights(n)
        assert np.all(np.isfinite(w))
    w1 = d.weights(1)
    np.testing.assert_allclose(w1, -w1[::-1], atol=1e-12 * np.abs(w1).max())
    assert d.weights(0).sum() == pytest.approx(1.0, rel=1e-12)


@pytest.mark.parametrize("alpha, beta", [(120, 120), (105, 140)])
def test_large_alpha_kernel_derivatives_in_closed_form(alpha, beta):
    """N = 0: g' = g·(α/τ − β/(T−τ)) and g'' = g·((α/τ − β/(T−τ))² − α/τ² − β/(T−τ)²), with g of
    (B.8) in log form; at α ≥ 100 the factorials alone overflow, so this needs log-gamma."""
    d = design(alpha=alpha, beta=beta, window=0.2, fs=1000)
    T = d.window_s
    tau = np.linspace(0.3, 0.7, 21) * T
    g = np.exp(
        math.lgamma(alpha + beta + 2)
        - math.lgamma(alpha + 1)
        - math.lgamma(beta + 1)
        + alpha * np.log(tau)
        + beta * np.log(T - tau)
        - (alpha + beta + 1) * math.log(T)
    )
    v = alpha / tau - beta / (T - tau)
    for n, expected in ((1, g * v), (2, g * (v**2 - alpha / tau**2 - beta / (T - tau) ** 2))):
        got = d.kernel(n, tau)
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-11 * np.abs(expected).max())


def test_large_alpha_kernel_derivatives_with_N_match_finite_differences():
    """N = 1, ϑ = 0.4, α = 105, β = 130: g⁽ⁿ⁾ equals the central difference of g⁽ⁿ⁻¹⁾ (Richardson)."""
    d = design(alpha=105, beta=130, N=1, theta=0.4, window=0.2, fs=1000)
    T = d.window_s
    tau = np.linspace(0.3, 0.65, 15) * T
    h = 1e-4 * T
    for n in (1, 2):

        def diff(step, n=n):
            return (d.kernel(n - 1, tau + step) - d.kernel(n - 1, tau - step)) / (2 * step)

        richardson = (4 * diff(h / 2) - diff(h)) / 3
        expected = d.kernel(n, tau)
        np.testing.assert_allclose(richardson, expected, rtol=0, atol=1e-7 * np.abs(expected).max())


def test_weights_cached_and_read_only():
    d = design(alpha=2, beta=2, window=0.05, fs=1000)
    assert d.weights(1) is d.weights(1)
    with pytest.raises(ValueError):
        d.weights(1)[0] = 1.0
    assert d == design(alpha=2, beta=2, window=0.05, fs=1000)  # the cache is not part of equality
    assert isinstance(d, Differentiator)


# --- the window in whole samples -----------------------------------------------------------------------


def test_window_from_n_s_over_fs_keeps_all_samples():
    """0.145 s · 200 Hz = 28.999999999999996 in floats: n_s must be 29, not 28."""
    assert 0.145 * 200 < 29
    assert design(alpha=2, beta=2, window=0.145, fs=200).n_s == 29
    for n_s in range(2, 400):
        for fs in (200.0, 4000.0, 32000.0, 3.0):
            assert whole_samples(n_s / fs * fs) == n_s
    assert whole_samples(28.9999999) == 29
    assert whole_samples(28.99) == 28


def test_window_floor_and_actual_cutoff():
    """n_s = floor(T·f_s), not rounded; T = n_s/f_s; the reported cutoff is the realised window's."""
    d = design(alpha=2, beta=2, window=0.01049, fs=1000)
    assert d.n_s == 10 and d.window_s == 0.01
    k_c = 60.0 ** (1 / 3)  # α = β = 2: ω_c·T = (Γ(6)/Γ(3))^(1/3)
    assert k_c / 250 * 4000 == pytest.approx(62.64, abs=0.01)  # rounding would give 63
    d = design(alpha=2, beta=2, omega_c=250, fs=4000)
    assert d.n_s == 62 and d.window_s == 62 / 4000
    assert d.omega_c_actual == pytest.approx(k_c * 4000 / 62, rel=1e-14)
    assert d.omega_c_actual > 250  # the shorter realised window has the higher cutoff


# --- bad input -----------------------------------------------------------------------------------------

GOOD = dict(alpha=2.0, beta=2.0, fs=1000.0, window=0.05)


@pytest.mark.parametrize(
    "changes, field, fragment",
    [
        ({"alpha": float("nan")}, "alpha", "finite"),
        ({"alpha": -1.0}, "alpha", "> -1"),
        ({"beta": -3.0}, "beta", "> -1"),
        ({"fs": -1.0}, "fs", "> 0"),
        ({"N": -1}, "N", "in 0..20"),
        ({"N": 21}, "N", "in 0..20"),
        ({"alpha": 1e6}, "alpha", "<= 200"),
        ({"beta": 201.0}, "beta", "<= 200"),
        ({"N": 1.5}, "N", "integer"),
        ({"window": None}, "omega_c", "exactly one"),
        ({"omega_c": 100.0}, "omega_c", "exactly one"),
        ({"window": -0.1}, "window", "> 0"),
        ({"window": 0.0015}, "window", "n_s >= 2"),
        ({"window": None, "omega_c": 1e6}, "omega_c", "<= "),
        ({"alpha": 9, "beta": 9, "window": 0.004}, "window", "Nyquist"),
        ({"theta": 0.5}, "theta", "N > 0"),
        ({"N": 1, "theta": 1.5}, "theta", "[-1, 1]"),
        ({"method": "simpson"}, "method", "midpoint"),
    ],
)
def test_invalid_design_raises_invalid_parameter(changes, field, fragment):
    with pytest.raises(InvalidParameter) as err:
        design(**{**GOOD, **changes})
    assert err.value.field == field
    assert fragment in str(err.value)


def test_nyquist_limit_names_the_allowed_cutoff():
    """α = β = 9: ω_c·T ≈ 14.2, so at 200 Hz n_s ≥ 5 keeps the realised cutoff below π·f_s."""
    with pytest.raises(InvalidParameter, match=r"omega_c: must be <= 568\.3"):
        design(alpha=9, beta=9, omega_c=600, fs=200)
    d = design(alpha=9, beta=9, omega_c=568, fs=200)
    assert d.n_s == 5 and d.omega_c_actual <= math.pi * 200


def test_order_limits():
    d = design(alpha=1.5, beta=0.5, window=0.05, fs=1000)
    assert d.max_order == 1
    d.weights(1)
    with pytest.raises(InvalidParameter, match=r"beta: must be > n - 1 = 1 for derivative order 2, got 0.5"):
        d.weights(2)
    for bad in (-1, 1.5, True, "two"):
        with pytest.raises(InvalidParameter, match="order"):
            d.weights(bad)
    trap = design(alpha=1.5, beta=2, window=0.05, fs=1000, method="trapezoidal")
    with pytest.raises(InvalidParameter, match="method: trapezoidal samples the window ends"):
        trap.weights(2)  # g'' ~ τ^{-0.5} is infinite at τ = 0


# --- properties over random designs --------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    alpha=st.floats(-0.9, 40),
    beta=st.floats(-0.9, 40),
    N=st.integers(0, 3),
    fs=st.sampled_from([20.0, 200.0, 1000.0, 4000.0, 32000.0]),
    n_s=st.integers(2, 3000),
    method=st.sampled_from(METHODS),
)
def test_any_valid_design_is_consistent(alpha, beta, N, fs, n_s, method):
    """Whatever the design: n_s survives window = n_s/f_s, the realised cutoff obeys the window rule
    and Nyquist, the delay lies inside the window, and the order-0 weights are a finite unit sum."""
    try:
        d = design(alpha=alpha, beta=beta, N=N, fs=fs, window=n_s / fs, method=method)
    except InvalidParameter as exc:  # only the Nyquist bound may reject these windows
        assert exc.field == "window" and "Nyquist" in str(exc)
        return
    assert d.n_s == n_s and d.window_s == n_s / fs
    assert d.omega_c_actual <= np.pi * fs
    assert d.omega_c_actual == pytest.approx(
        design(alpha=alpha, beta=beta, N=N, fs=fs, window=d.window_s).omega_c_actual
    )
    assert 0.0 <= d.delay_s <= d.window_s  # N > 0: the default ϑ is a root in (-1, 1)
    if method != "trapezoidal" or min(alpha, beta) >= 0:
        w = d.weights(0)
        assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0, rel=1e-9)


def test_cutoff_of_arcsine_kernel_below_mu_one_half():
    """α = β = −1/2 (μ = 1/2, κ = 0), N = 0: ω_c T = (Γ(1)/Γ(1/2))^{1/μ} = 1/π (Othmane et al.
    2022, eq. (31)); the i = 0 term (2μ+κ−1)Γ(2μ+κ−1) is taken as Γ(2μ+κ), not log(0) + lgamma(0)."""
    from labrunner.differentiators.kernel import log_cutoff_product

    assert math.exp(log_cutoff_product(-0.5, -0.5, 0, 0.0)) == pytest.approx(1.0 / math.pi, rel=1e-12)
    d = design(alpha=-0.5, beta=-0.5, N=0, fs=20.0, window=0.1)
    assert d.n_s == 2 and np.isfinite(d.omega_c_actual)


def test_rho_zero_for_alpha_plus_beta_at_most_minus_one():
    """ρ_0 = 2^{α+β+1}/‖P_0‖² = Γ(α+β+2)/(Γ(α+1)Γ(β+1)) (the Beta-function normalisation); at
    α = β = −1/2 that is 1/π, where (α+β+1)·Γ(α+β+1) is 0·∞ in the two-term form."""
    from labrunner.differentiators.kernel import log_rho

    assert math.exp(log_rho(-0.5, -0.5, 0)) == pytest.approx(1.0 / math.pi, rel=1e-12)
    assert math.exp(log_rho(-0.7, -0.6, 0)) == pytest.approx(
        math.gamma(0.7) / (math.gamma(0.3) * math.gamma(0.4)), rel=1e-12
    )
    for method in ("midpoint", "analytic"):
        w = design(alpha=-0.5, beta=-0.5, N=0, fs=20.0, window=0.1, method=method).weights(0)
        assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0, rel=1e-9)
