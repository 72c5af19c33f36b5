"""The kernel's own x·log(y) and Jacobi polynomials against scipy.special, their reference: the
kernel (and so every differentiator's weights) must come out bit for bit as when it evaluated
them with scipy.special.xlogy and eval_jacobi (x86-64, whose scipy wheels use no fused
multiply-add; elsewhere within 2 ulp)."""

from __future__ import annotations

import itertools
import math
import platform

import numpy as np
import pytest
from scipy import special

from labrunner.differentiators import design
from labrunner.differentiators.kernel import jacobi, kernel_u, log_rho, xlogy

EXACT = platform.machine().lower() in ("x86_64", "amd64")


def _same(got, want) -> None:
    got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
    if EXACT:
        np.testing.assert_array_equal(got, want)
    else:
        np.testing.assert_array_max_ulp(got, want, maxulp=2)


def _kernel_with_scipy(alpha, beta, N, theta, k, u):
    """The kernel as it was written with scipy.special: the plain reference."""
    u = np.asarray(u, dtype=float)
    uc = np.clip(u, 0.0, 1.0)
    nu = 1.0 - 2.0 * uc
    a, b = alpha - k, beta - k
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        log_w = special.xlogy(a, uc) + special.xlogy(b, 1.0 - uc)
        lr0 = log_rho(alpha, beta, 0)
        total = np.zeros_like(uc)
        first = 1 if k == -1 else 0
        for i in range(first, N + 1):
            c = special.eval_jacobi(i, alpha, beta, theta) * math.exp(
                log_rho(alpha, beta, i) - lr0 + math.lgamma(i + k + 1) - math.lgamma(i + 1)
            )
            total = total + c * special.eval_jacobi(i + k, a, b, nu)
        out = np.exp(log_w + lr0) * total if N >= first else np.zeros_like(uc)
    if k == -1:
        out = out + special.betainc(alpha + 1.0, beta + 1.0, uc)
        return np.where(u < 0.0, 0.0, np.where(u > 1.0, 1.0, out))
    return np.where((u >= 0.0) & (u <= 1.0), out, 0.0)


X = np.concatenate([np.linspace(-1.0, 1.0, 401), [-0.999999, 0.3, 0.999999]])


@pytest.mark.parametrize("n", range(25))
def test_jacobi_polynomials_equal_scipy_eval_jacobi(n):
    for alpha, beta in itertools.product([-0.9, -0.5, 0.0, 0.5, 1.0, 2.0, 3.5, 8.0, 9.0, 30.0, 199.0], repeat=2):
        _same(jacobi(n, alpha, beta, X), special.eval_jacobi(n, alpha, beta, X))
        _same(jacobi(n, alpha, beta, 0.37), special.eval_jacobi(n, alpha, beta, 0.37))


def test_jacobi_agrees_with_the_closed_forms():
    """P_1^{(a,b)}(x) = (a+1) + (a+b+2)(x−1)/2; P_n^{(0,0)} is Legendre's P_n; P_n(1) = C(n+a, n)."""
    np.testing.assert_allclose(jacobi(1, 2.0, 3.0, X), 3.0 + 7.0 * (X - 1.0) / 2.0, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(jacobi(3, 0.0, 0.0, X), (5 * X**3 - 3 * X) / 2, atol=1e-14)
    assert jacobi(4, 2.5, 1.0, 1.0) == pytest.approx(math.comb(6, 4) * 0 + special.binom(6.5, 4), rel=1e-15)


def test_xlogy_equals_scipy_xlogy_at_every_edge():
    y = np.array([0.0, 1e-300, 1e-12, 0.25, 0.5, 0.75, 1.0 - 1e-16, 1.0, 2.0, np.nan, -1.0, np.inf])
    y = np.concatenate([y, np.random.default_rng(1).random(5000)])
    with np.errstate(invalid="ignore", divide="ignore"):
        for a in (0.0, -0.5, 0.5, 1.0, 2.0, 8.0, 9.0, 199.0):
            _same(xlogy(a, y), special.xlogy(a, y))
    assert xlogy(2.0, np.zeros((2, 3))).shape == (2, 3)


@pytest.mark.parametrize("N", [0, 1, 2, 4])
def test_the_kernel_equals_its_scipy_form(N):
    u = np.concatenate([(np.arange(57) + 0.5) / 57, np.arange(58) / 57, [-0.1, 1.1]])
    for alpha, beta in [(9.0, 9.0), (3.0, 1.0), (0.5, 2.0), (2.0, 2.0), (30.0, 12.0), (199.0, 150.0)]:
        theta = (beta - alpha) / (alpha + beta + 2.0) if N == 0 else 0.3
        for k in range(-1, 3):
            if min(alpha, beta) <= k - 1:
                continue
            with np.errstate(all="ignore"):
                _same(kernel_u(alpha, beta, N, theta, k, u), _kernel_with_scipy(alpha, beta, N, theta, k, u))


def test_the_thesis_differentiators_keep_their_weights():
    """The designs of the campaigns (motor 200 Hz, valve 4 kHz, plate 32 kHz): weights as before."""
    for kw in (
        {"alpha": 9, "beta": 9, "fs": 200.0, "omega_c": 200.0},
        {"alpha": 4, "beta": 4, "fs": 4000.0, "omega_c": 800.0, "method": "trapezoidal"},
        {"alpha": 3, "beta": 3, "N": 1, "fs": 32000.0, "omega_c": 900.0, "method": "analytic"},
    ):
        d = design(**kw)
        for order in range(3):
            ns = d.n_s
            if d.method == "midpoint":
                raw = _kernel_with_scipy(d.alpha, d.beta, d.N, d.theta, order, (np.arange(ns) + 0.5) / ns)
            elif d.method == "analytic":
                raw = np.diff(_kernel_with_scipy(d.alpha, d.beta, d.N, d.theta, order - 1, np.arange(ns + 1) / ns))
            else:
                raw = _kernel_with_scipy(d.alpha, d.beta, d.N, d.theta, order, np.arange(ns + 1) / ns)
                raw[0] *= 0.5
                raw[-1] *= 0.5
            j = np.arange(raw.size, dtype=float)
            phi = float(np.sum(raw * (-j / d.fs) ** order)) / math.factorial(order)
            _same(d.weights(order), raw / phi)
