"""Rightmost characteristic roots and the spectral abscissa of a delay equation, computed without
any closed form: Chebyshev collocation of the infinitesimal generator (Breda, Maset & Vermiglio,
SIAM J. Sci. Comput. 27 (2005) 482-495; the method behind TDS-CONTROL's ``tds_roots``), then
Newton's method on the characteristic function Δ(s) itself.

Why two stages: the collocation eigenvalues approximate the rightmost roots spectrally well
(errors ~1e-8 with 24 nodes), Newton on Δ makes every accepted root exact to rounding and rejects
anything that is not a root of Δ. So an accepted root is always genuine; a root can only be
missed, never invented, and the tests compare against Lambert W and against the closed forms.

Neutral equations (thesis (A.11)): the splicing row of the generator carries the delayed
derivative as the derivative of the collocation polynomial at −τ (row ℓ(−τ)ᵀ·D). Their roots form
chains that accumulate at Re s = c_D, the spectral abscissa of the difference operator
y⁽ⁿ⁾(t) + b·y⁽ⁿ⁾(t − τ) = 0, i.e. c_D = ln|b|/τ (Hale & Verduyn Lunel, ch. 9). Chain roots at large
|Im s| are not resolved by any finite discretisation, so the neutral spectral abscissa is reported
as max(c_D, rightmost resolved root); neutral terms at one delay only.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from labrunner.errors import InvalidParameter
from labrunner.stability.quasipoly import QuasiPolynomial

DEFAULT_NODES = 24
_NEWTON_ITER = 40


@lru_cache(maxsize=16)
def _chebyshev(n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chebyshev extremal nodes on [−1, 0] (θ_0 = 0, θ_N = −1), their differentiation matrix
    (Trefethen, Spectral Methods in MATLAB, ``cheb``) and barycentric weights."""
    j = np.arange(n_nodes + 1)
    x = np.cos(np.pi * j / n_nodes)
    c = np.where((j == 0) | (j == n_nodes), 2.0, 1.0) * (-1.0) ** j
    dx = x[:, None] - x[None, :] + np.eye(n_nodes + 1)
    d = np.outer(c, 1.0 / c) / dx
    d -= np.diag(d.sum(axis=1))
    weights = (-1.0) ** j * np.where((j == 0) | (j == n_nodes), 0.5, 1.0)
    return (x - 1.0) / 2.0, 2.0 * d, weights


def _interpolation_row(theta: np.ndarray, weights: np.ndarray, point: float) -> np.ndarray:
    """Lagrange basis ℓ_j(point) on the nodes (barycentric formula, exact at a node)."""
    diff = point - theta
    hit = np.flatnonzero(np.abs(diff) < 1e-14)
    if hit.size:
        row = np.zeros_like(theta)
        row[hit[0]] = 1.0
        return row
    terms = weights / diff
    return terms / terms.sum()


def generator_matrix(qp: QuasiPolynomial, n_nodes: int = DEFAULT_NODES) -> np.ndarray:
    """Collocation of the infinitesimal generator of ``qp`` in normalised time (largest delay 1):
    an n(N+1) square matrix whose eigenvalues approximate the roots of ``qp.scaled()``.

    State: y and its first n−1 derivatives at the nodes, node-major. Rows of nodes 1..N
    differentiate the collocation polynomial; the rows of node 0 impose the equation
    x'(0) = A_0 x(0) + Σ_k A_k x(−τ_k) + Σ_k B_k x'(−τ_k) (companion form of Δ).
    """
    q = qp.scaled()
    n = q.degree
    c = q.coeffs / q.coeffs[0, 0]
    theta, diff, weights = _chebyshev(n_nodes)
    size = n * (n_nodes + 1)
    m = np.zeros((size, size))
    m[n:, :] = np.kron(diff[1:, :], np.eye(n))
    for k, tau in enumerate(q.delays):
        ell = np.zeros(n_nodes + 1)
        ell[0] = 1.0
        if k:
            ell = _interpolation_row(theta, weights, -tau)
        lower = np.zeros((n, n))
        if k == 0:
            lower[:-1, 1:] = np.eye(n - 1)
        lower[-1, :] = -c[k, :0:-1]  # −c_{k,i} for powers i = 0..n−1
        m[:n, :] += np.kron(ell, lower)
        if k and c[k, 0] != 0.0:
            neutral = np.zeros((n, n))
            neutral[-1, -1] = -c[k, 0]
            m[:n, :] += np.kron(ell @ diff, neutral)
    return m


def _newton(q: QuasiPolynomial, start: np.ndarray) -> np.ndarray:
    """Newton's method on Δ from every start at once; returns the converged roots only."""
    s = start.astype(complex)
    step = np.full(s.shape, np.inf, dtype=complex)
    for _ in range(_NEWTON_ITER):
        f, df, _ = q.evaluate(s)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(df != 0, f / df, np.inf)
        s = s - step
        if np.all(~np.isfinite(s) | (np.abs(step) <= 1e-14 * (1.0 + np.abs(s)))):
            break
    f, _, size = q.evaluate(np.where(np.isfinite(s), s, 0.0))
    ok = np.isfinite(s) & (np.abs(step) <= 1e-9 * (1.0 + np.abs(s))) & (np.abs(f) <= 1e-9 * np.maximum(size, 1.0))
    return s[ok]


def _unique(roots: np.ndarray) -> np.ndarray:
    """Upper-half-plane representatives, duplicates merged, sorted by real part (descending)."""
    roots = np.where(roots.imag < 0, roots.conj(), roots)
    roots = np.where(np.abs(roots.imag) <= 1e-10 * (1.0 + np.abs(roots)), roots.real + 0j, roots)
    roots = roots[np.argsort(-roots.real, kind="stable")]
    kept: list[complex] = []
    for r in roots:
        if all(abs(r - k) > 1e-8 * (1.0 + abs(r)) for k in kept):
            kept.append(complex(r))
    return np.array(kept, dtype=complex)


def _refined(qp: QuasiPolynomial, count: int, n_nodes: int) -> tuple[np.ndarray, float]:
    """Newton-refined rightmost roots (scaled back to 1/s) and the collocation's own rightmost
    real part [1/s], the fallback should Newton reject every candidate."""
    if qp.tau_max == 0.0:
        roots = np.roots(qp.coeffs[0])
        return _unique(roots)[:count], float(roots.real.max())
    eig = np.linalg.eigvals(generator_matrix(qp, n_nodes))
    eig = eig[eig.imag >= -1e-9]
    start = eig[np.argsort(-eig.real)][: max(2 * count, 8)]
    return _unique(_newton(qp.scaled(), start))[:count] / qp.tau_max, float(start[0].real) / qp.tau_max


def rightmost_roots(qp: QuasiPolynomial, count: int = 6, *, n_nodes: int = DEFAULT_NODES) -> np.ndarray:
    """The ``count`` rightmost roots of Δ [1/s], one of each conjugate pair (Im ≥ 0), sorted by
    real part (descending). Every returned value is a Newton-converged root of Δ."""
    if count < 1:
        raise InvalidParameter("count", f"must be >= 1, got {count}")
    return _refined(qp, count, n_nodes)[0]


def difference_abscissa(qp: QuasiPolynomial) -> float:
    """c_D = ln|b|/τ of the neutral difference operator (−inf for a retarded ``qp``)."""
    b = qp.neutral_terms
    active = np.flatnonzero(b)
    if active.size == 0:
        return -np.inf
    if active.size > 1:
        raise InvalidParameter("coeffs", "neutral terms are supported at one delay only")
    return float(np.log(abs(b[active[0]])) / qp.delays[active[0] + 1])


def spectral_abscissa(qp: QuasiPolynomial, *, n_nodes: int = DEFAULT_NODES) -> float:
    """Spectral abscissa max Re s over the roots of Δ [1/s]; < 0 means exponentially stable.

    Neutral ``qp``: max(c_D, rightmost resolved root), see the module docstring. Should Newton
    reject every candidate, the collocation eigenvalue stands in (never a silent −inf).
    """
    roots, collocated = _refined(qp, 1, n_nodes)
    resolved = float(roots[0].real) if roots.size else collocated
    return max(resolved, difference_abscissa(qp))
