"""Jacobi kernels of the algebraic differentiators (thesis Sec. 2.1, (2.2)-(2.3), Remark 2.2).

Everything here is written on the normalised time ``u = τ/T ∈ [0, 1]`` and in log-gamma form, so
that large α, β (≥ 100) neither overflow nor underflow. With ν = 1 − 2u the kernel (2.2) is

    g(τ) = (2/T) Σ_{i=0}^{N} P_i(ϑ)/‖P_i‖² · w^{(α,β)}(ν) P_i(ν),

and its k-th derivative follows from d/dν[w^{(a,b)} P_m^{(a,b)}] = −2(m+1) w^{(a−1,b−1)} P_{m+1}^{(a−1,b−1)}:

    g^{(k)}(τ) = T^{−(k+1)} u^{α−k} (1−u)^{β−k} Σ_i ρ_i P_i(ϑ) (i+k)!/i! · P_{i+k}^{(α−k,β−k)}(ν),

with ρ_i = 2^{α+β+1}/‖P_i‖² = i! (2i+α+β+1) Γ(i+α+β+1) / (Γ(i+α+1) Γ(i+β+1)). The same formula with
k = −1 is the antiderivative ∫₀^τ g of the terms i ≥ 1; the i = 0 term integrates to the
regularised incomplete beta function I_u(α+1, β+1) (ρ_0 = 1/B(α+1, β+1)).
"""

from __future__ import annotations

import math

import numpy as np

# The kernel needs no scipy.special (~0.15-0.3 s to import), so that validating a campaign can form
# every design's weights (a window whose normalisation vanishes is refused before anything runs):
# x·log(y) and the Jacobi polynomials are evaluated here exactly as scipy.special.xlogy and
# eval_jacobi evaluate them (bit-identical: tests/test_differentiators_kernel.py). scipy.special is
# imported only for the antiderivative (k = −1: betainc), the roots of P_{N+1} (ϑ for N > 0) and
# polynomial degrees of 20 and more.

_BINOM_PRODUCT = 20  # scipy.special.binom(n, k) multiplies out integer k below this; above, a beta function


def _log(v: float) -> float:
    """libm's log (math.log) with log(0) = −inf and log(v < 0) = nan, as C's log."""
    if v > 0.0:
        return math.log(v)
    return -math.inf if v == 0.0 else math.nan


def xlogy(a: float, y: np.ndarray) -> np.ndarray:
    """a·log(y), 0 where a = 0 (unless y is nan), elementwise: scipy.special.xlogy. Through libm's
    log one value at a time: numpy's own log differs from it in the last bit on AVX-512 machines."""
    y = np.asarray(y, dtype=float)
    if a == 0.0:
        return np.where(np.isnan(y), np.nan, 0.0)
    return np.array([a * _log(v) for v in y.ravel().tolist()], dtype=float).reshape(y.shape)


def _binom(n: float, k: int) -> float:
    """The binomial coefficient C(n, k) for a real n and an integer 0 <= k < 20, by the product
    formula (with its symmetry for a positive integer n) that scipy.special.binom uses there."""
    kx = float(k)
    if n == math.floor(n) and kx > math.floor(n) / 2 and n > 0:
        kx = math.floor(n) - kx
    num = den = 1.0
    for i in range(1, int(kx) + 1):
        num *= i + n - kx
        den *= i
        if abs(num) > 1e50:
            num /= den
            den = 1.0
    return num / den


def jacobi(n: int, alpha: float, beta: float, x: np.ndarray | float) -> np.ndarray | float:
    """P_n^{(α,β)}(x) for an integer degree n >= 0 (α, β > −1): the three-term recurrence of
    scipy.special.eval_jacobi's integer-degree loop, term by term in its order of operations."""
    if n >= _BINOM_PRODUCT or abs(n + alpha) <= 1e-8:  # scipy's binom takes its beta-function branch
        from scipy import special

        return special.eval_jacobi(n, alpha, beta, x)
    if n == 0:
        return np.ones_like(x, dtype=float) if np.ndim(x) else 1.0
    if n == 1:
        return 0.5 * (2 * (alpha + 1) + (alpha + beta + 2) * (x - 1))
    d = (alpha + beta + 2) * (x - 1) / (2 * (alpha + 1))
    p = d + 1
    for kk in range(n - 1):
        k = kk + 1.0
        t = 2 * k + alpha + beta
        d = ((t * (t + 1) * (t + 2)) * (x - 1) * p + 2 * k * (k + beta) * (t + 2) * d) / (
            2 * (k + alpha + 1) * (k + alpha + beta + 1) * t
        )
        p = d + p
    return _binom(n + alpha, n) * p


def log_rho(alpha: float, beta: float, i: int) -> float:
    """log ρ_i = log(2^{α+β+1}/‖P_i^{(α,β)}‖²) (thesis Remark 2.2), via log-gamma.

    For i = 0 and α + β + 1 ≤ 0 the factor (2i+α+β+1)·Γ(i+α+β+1) is taken as Γ(α+β+2) > 0
    (Γ(x+1) = xΓ(x)); the two-term form would be log(0) or the log of a negative number."""
    if 2 * i + alpha + beta + 1 <= 0.0:
        lead = math.lgamma(alpha + beta + 2)
    else:
        lead = math.log(2 * i + alpha + beta + 1) + math.lgamma(i + alpha + beta + 1)
    return math.lgamma(i + 1) + lead - math.lgamma(i + alpha + 1) - math.lgamma(i + beta + 1)


def kernel_u(alpha: float, beta: float, N: int, theta: float, k: int, u: np.ndarray) -> np.ndarray:
    """T^{k+1}·g^{(k)}(uT) for k ≥ 0, or ∫₀^{uT} g for k = −1 (dimensionless), at normalised times u.

    Outside [0, 1] the kernel and its derivatives are 0 and the antiderivative is 0 before the
    window and 1 after it. At u ∈ {0, 1} the factor u^{α−k} follows x^0 = 1 and 0^{a<0} = inf
    (a kernel derivative that is singular at the window ends).
    """
    u = np.asarray(u, dtype=float)
    inside = (u >= 0.0) & (u <= 1.0)
    uc = np.clip(u, 0.0, 1.0)
    nu = 1.0 - 2.0 * uc
    a, b = alpha - k, beta - k
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        log_w = xlogy(a, uc) + xlogy(b, 1.0 - uc)
        lr0 = log_rho(alpha, beta, 0)
        total = np.zeros_like(uc)
        first = 1 if k == -1 else 0
        for i in range(first, N + 1):
            c = jacobi(i, alpha, beta, theta) * math.exp(
                log_rho(alpha, beta, i) - lr0 + math.lgamma(i + k + 1) - math.lgamma(i + 1)
            )
            total = total + c * jacobi(i + k, a, b, nu)
        out = np.exp(log_w + lr0) * total if N >= first else np.zeros_like(uc)
    if k == -1:
        from scipy import special

        out = out + special.betainc(alpha + 1.0, beta + 1.0, uc)
        return np.where(u < 0.0, 0.0, np.where(u > 1.0, 1.0, out))
    return np.where(inside, out, 0.0)


def default_theta(alpha: float, beta: float, N: int) -> float:
    """ϑ for N > 0: the largest root of P_{N+1}^{(α,β)}, which minimises the delay while keeping the
    higher degree of exactness (AlgDiff's default; Othmane et al. 2022, Sec. 4.1). For N = 0 the
    equivalent ϑ = (β−α)/(α+β+2) (root of P_1) makes δ_t = (1−ϑ)T/2 agree with (2.3)."""
    if N == 0:
        return (beta - alpha) / (alpha + beta + 2.0)
    from scipy import special  # here: N = 0 (reading a delay, as analyse does) needs none

    roots, _ = special.roots_jacobi(N + 1, alpha, beta)
    return float(np.max(roots))


def log_cutoff_product(alpha: float, beta: float, N: int, theta: float) -> float:
    """log(ω_c·T), the cutoff–window relation of Othmane et al. (2022, Sec. 4.2.2, eq. (31)).

    μ = 1 + min(α, β), κ = |α − β|; for N = 0 it reduces to ω_c T = (Γ(2μ+κ)/Γ(μ+κ))^{1/μ}.
    For N > 0 the constant is q/Γ(μ+κ) with q from the sums r, s of the amplitude asymptotes
    (as AlgDiff's ``computeTfromWc``), evaluated in log-gamma form relative to the i = 0 term.
    Returns −inf where ϑ makes the asymptote vanish (no cutoff is defined).
    """
    if N:  # N = 0 (only P_0 = 1 below, as when analyse reads a delay) needs no scipy.special (~0.1 s)
        from scipy import special
    mu = 1.0 + min(alpha, beta)
    kappa = abs(alpha - beta)
    sigma = 1.0 if beta >= alpha else -1.0
    ref = math.lgamma(2 * mu + kappa) - math.lgamma(mu + kappa)  # log r for N = 0
    r = s = 0.0  # r/e^ref and, used only for κ = 0 where Γ(μ+κ+i) = Γ(μ+i), s/e^ref
    for i in range(N + 1):
        if 2 * mu + kappa + 2 * i - 1 <= 0.0:  # i = 0, μ ≤ 1/2: (2μ+κ−1)·Γ(2μ+κ−1) = Γ(2μ+κ) > 0
            log_ci = math.lgamma(2 * mu + kappa)
        else:
            log_ci = math.log(2 * mu + kappa + 2 * i - 1) + math.lgamma(2 * mu + kappa + i - 1)
        term = math.exp(log_ci - math.lgamma(mu + kappa + i) - ref)
        if i:  # P_0 = 1
            term *= special.eval_jacobi(i, mu - 1, mu + kappa - 1, sigma * theta)
        r += term
        s += (-1) ** i * term
    q_rel = max(abs(r), abs(s)) if kappa == 0 else abs(r)
    return (ref + math.log(q_rel)) / mu if q_rel > 0.0 else -math.inf
