"""The generalised unknown-part estimator against the classical closed forms of the literature:
α = β = 1 against thesis (2.18), α = β = 2 against thesis (2.23) (= paper 2 eq. (22)), both
discretised by the mid-point rule, normalised by thesis (2.4), with ε = t_s (thesis (3.4))."""

import math

import numpy as np
import pytest

from labrunner.control.estimators import MFCEstimator
from labrunner.differentiators import design

FS = 1000.0
TS = 1.0 / FS


def classical_kernels(order: int, T: float, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y-kernel, u-kernel/γ) of (2.18) for order 1 and of (2.23) for order 2, at σ = t − τ − ε."""
    if order == 1:
        return 6.0 / T**3 * (T - 2.0 * sigma), 6.0 / T**3 * sigma * (T - sigma)
    return 120.0 / (2 * T**5) * (T**2 - 6 * T * sigma + 6 * sigma**2), 120.0 / (2 * T**5) * sigma**2 * (
        T - sigma
    ) ** 2 / 2


def normalised(w: np.ndarray, n: int) -> np.ndarray:
    """(1/Φ_n)·w with Φ_n = t_sⁿ/n!·Σ_j w[j](−j)ⁿ (thesis (2.4))."""
    j = np.arange(w.size)
    return w / (TS**n / math.factorial(n) * np.sum(w * (-j) ** n))


@pytest.mark.parametrize("order, n_s", [(1, 14), (1, 37), (2, 20), (2, 61)])
def test_generalised_estimate_equals_the_classical_formula(order, n_s):
    d = design(alpha=order, beta=order, fs=FS, window=n_s / FS)
    T = n_s * TS
    sigma = (np.arange(n_s) + 0.5) * TS  # mid-point nodes, newest sample first
    ky, ku = classical_kernels(order, T, sigma)
    wy, wu = normalised(TS * ky, order), normalised(TS * ku, 0)

    rng = np.random.default_rng(order * 100 + n_s)
    K, gamma = 300, 3.7
    y = np.cumsum(rng.normal(size=K)) * 0.1
    v = rng.normal(size=K)
    est = MFCEstimator([d], order, gamma)
    est.reset(np.array([[y[0]]]), 0.0, np.array([[0.0]]))
    y_hist = np.concatenate([np.full(n_s + 1, y[0]), y])  # the stationary past of reset
    v_hist = np.concatenate([np.zeros(n_s + 1), v])
    off = n_s + 1
    for k in range(K):
        v_prev = v_hist[off + k - 1]
        est.step(np.array([[y[k]]]), np.array([[v_prev]]), np.zeros((1, 1, 4)))
        ys = y_hist[off + k - 1 - np.arange(n_s)]  # y[k−1−j]
        vs = v_hist[off + k - 1 - np.arange(n_s)]  # v[k−1−j]
        classical = np.dot(wy, ys) - gamma * np.dot(wu, vs)
        assert est.f_hat[0, 0] == pytest.approx(classical, abs=1e-10 * max(1.0, abs(classical)))


@pytest.mark.parametrize("order", [1, 2])
def test_the_kernels_are_the_classical_ones(order):
    """The continuous kernels g⁽ⁿ⁾ and g of the differentiator are those of (2.18)/(2.23)."""
    d = design(alpha=order, beta=order, fs=FS, window=0.05)
    tau = np.linspace(0.0, d.window_s, 101)
    ky, ku = classical_kernels(order, d.window_s, tau)
    np.testing.assert_allclose(d.kernel(order, tau), ky, rtol=1e-10, atol=1e-10 * np.abs(ky).max())
    np.testing.assert_allclose(d.kernel(0, tau), ku, rtol=1e-10, atol=1e-10 * np.abs(ku).max())


def test_error_filters_and_measurement_filters():
    """ê = Σ ŵ0 e[k−j], ê̇ = Σ ŵ1 e[k−j]; with the measurement filtered, ê = ŷ − y_r, ê̇ = ŷ̇ − ẏ_r."""
    d = design(alpha=3, beta=3, fs=FS, omega_c=300.0)
    w0, w1 = d.weights(0), d.weights(1)
    rng = np.random.default_rng(1)
    K = 200
    y, yr = rng.normal(size=K), rng.normal(size=(K, 4))
    mixed = MFCEstimator([d, d], 2, filter_error=np.array([True, False]))
    both = MFCEstimator([d, d], 2, filter_error=True), MFCEstimator([d, d], 2, filter_error=False), mixed
    for est in both:
        est.reset(np.zeros((2, 1)), 0.0, np.zeros((2, 1)))
    hist = np.concatenate([np.zeros(d.n_s), y])
    ehist = np.concatenate([np.zeros(d.n_s), y - yr[:, 0]])
    for k in range(K):
        r = np.broadcast_to(yr[k], (2, 1, 4))
        for est in both:
            est.step(np.full((2, 1), y[k]), np.zeros((2, 1)), r)
        window = d.n_s + k - np.arange(d.n_s)
        assert both[0].e_hat[0, 0] == pytest.approx(np.dot(w0, ehist[window]), abs=1e-12)
        assert both[0].de_hat[1, 0] == pytest.approx(np.dot(w1, ehist[window]), abs=1e-9)
        assert both[1].e_hat[0, 0] == pytest.approx(np.dot(w0, hist[window]) - yr[k, 0], abs=1e-12)
        assert both[1].de_hat[1, 0] == pytest.approx(np.dot(w1, hist[window]) - yr[k, 1], abs=1e-9)
        np.testing.assert_array_equal(mixed.e_hat[:, 0], [both[0].e_hat[0, 0], both[1].e_hat[1, 0]])


def test_constant_unknown_part_is_recovered_exactly_on_a_ramp():
    """ẏ = f + ρ·u with u constant: y is affine, the estimate is exact (γ = ρ) for any window."""
    f, rho, u = -2.5, 4.0, 0.3
    for order, a in ((1, 1.0), (1, 5.0)):
        d = design(alpha=a, beta=a, fs=FS, omega_c=200.0)
        est = MFCEstimator([d], order, rho)
        est.reset(np.zeros((1, 1)), 0.0, np.full((1, 1), u))
        y = 0.0
        # a stationary past is not a ramp: run past one window first
        for _ in range(d.n_s + 5):
            y += TS * (f + rho * u)
            est.step(np.array([[y]]), np.full((1, 1), u), np.zeros((1, 1, 4)))
        assert est.f_hat[0, 0] == pytest.approx(f, abs=1e-9)
