"""Stability boundaries and maps from the spectral abscissa alone (no closed form involved).

A boundary in one gain is a zero of the spectral abscissa α(k): the scan samples α on a grid,
refines every change of the sign of α with Brent's method (α is continuous in k for retarded
equations), and looks between samples for dips below zero (or bumps above it) that the grid
stepped over, by minimising (maximising) α around each sampled local extremum.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from labrunner.brent import brent_root
from labrunner.errors import InvalidParameter, check_finite
from labrunner.stability.quasipoly import QuasiPolynomial
from labrunner.stability.spectrum import DEFAULT_NODES, spectral_abscissa

Family = Callable[[float], QuasiPolynomial]
Family2 = Callable[[float, float], QuasiPolynomial]


def _abscissa(family: Family, n_nodes: int) -> Callable[[float], float]:
    return lambda k: spectral_abscissa(family(float(k)), n_nodes=n_nodes)


def _extremum_crossings(
    alpha: Callable[[float], float], grid: np.ndarray, values: np.ndarray, tol: float
) -> list[float]:
    """Zeros of α hidden between samples: around each sampled local minimum with α > 0 (maximum with
    α < 0) find the extremum; if it has the other sign, bracket the zero on both sides of it."""
    from scipy.optimize import minimize_scalar  # here: the closed-form bounds import this module

    out: list[float] = []
    for i in range(1, len(grid) - 1):
        v = values[i - 1 : i + 2]
        for sign in (1.0, -1.0):
            if sign * v[1] > 0 and sign * v[1] <= sign * v[0] and sign * v[1] <= sign * v[2]:
                res = minimize_scalar(
                    lambda k: sign * alpha(k),
                    bounds=(grid[i - 1], grid[i + 1]),
                    method="bounded",
                    options={"xatol": tol},
                )
                if sign * res.fun < 0:
                    out.append(brent_root(alpha, grid[i - 1], res.x, xtol=tol, rtol=1e-14))
                    out.append(brent_root(alpha, res.x, grid[i + 1], xtol=tol, rtol=1e-14))
    return out


def gain_boundaries(
    family: Family, lo: float, hi: float, *, n_scan: int = 101, n_nodes: int = DEFAULT_NODES
) -> np.ndarray:
    """Gains k ∈ (lo, hi) where the spectral abscissa of ``family(k)`` crosses zero, ascending.

    ``family`` maps a gain to the characteristic quasi-polynomial; ``n_scan`` samples cover
    [lo, hi]; each crossing is refined to ~1e-13·max(|lo|, |hi|).
    """
    lo, hi = check_finite("lo", lo), check_finite("hi", hi)
    if not lo < hi or n_scan < 3:
        raise InvalidParameter("hi", f"must exceed lo = {lo} with n_scan >= 3, got {hi}, {n_scan}")
    alpha = _abscissa(family, n_nodes)
    tol = 1e-13 * max(abs(lo), abs(hi))
    grid = np.linspace(lo, hi, n_scan)
    values = np.array([alpha(k) for k in grid])
    stable = values < 0
    found = [
        brent_root(alpha, grid[i], grid[i + 1], xtol=tol, rtol=1e-14) for i in np.flatnonzero(stable[:-1] != stable[1:])
    ]
    found += _extremum_crossings(alpha, grid, values, tol)
    return np.unique(np.array(found, dtype=float))


def stable_intervals(
    family: Family, lo: float, hi: float, *, n_scan: int = 101, n_nodes: int = DEFAULT_NODES
) -> list[tuple[float, float]]:
    """Open intervals of k ∈ [lo, hi] where ``family(k)`` is exponentially stable (α < 0).
    An interval that ends at ``lo`` or ``hi`` is cut by the scan window."""
    edges = np.concatenate([[lo], gain_boundaries(family, lo, hi, n_scan=n_scan, n_nodes=n_nodes), [hi]])
    alpha = _abscissa(family, n_nodes)
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a and alpha(0.5 * (a + b)) < 0]


def _min_over_y(family: Family2, x: float, y: np.ndarray, n_nodes: int) -> float:
    """min over y of α(x, y): the best of the samples ``y``, polished by bounded Brent around it."""
    from scipy.optimize import minimize_scalar  # here: the closed-form bounds import this module

    values = np.array([spectral_abscissa(family(x, float(yi)), n_nodes=n_nodes) for yi in y])
    i = int(np.argmin(values))
    lo, hi = y[max(i - 1, 0)], y[min(i + 1, len(y) - 1)]
    res = minimize_scalar(
        lambda yi: spectral_abscissa(family(x, float(yi)), n_nodes=n_nodes),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": 1e-13 * max(abs(y[0]), abs(y[-1]))},
    )
    return float(min(res.fun, values[i]))


def projected_intervals(
    family: Family2,
    x_lo: float,
    x_hi: float,
    y_lo: float,
    y_hi: float,
    *,
    n_x: int = 25,
    n_y: int = 41,
    n_nodes: int = DEFAULT_NODES,
) -> list[tuple[float, float]]:
    """Intervals of x for which some y ∈ [y_lo, y_hi] makes ``family(x, y)`` stable: the projection
    of the stable set, e.g. the k_d range of a second-order loop. Edges are the zeros of
    m(x) = min_y α(x, y) (continuous), bracketed on ``n_x`` samples and refined by Brent's method."""
    y = np.linspace(y_lo, y_hi, n_y)
    m = lambda x: _min_over_y(family, float(x), y, n_nodes)  # noqa: E731
    grid = np.linspace(x_lo, x_hi, n_x)
    stable = np.array([m(x) for x in grid]) < 0
    tol = 1e-13 * max(abs(x_lo), abs(x_hi))
    edges = [
        brent_root(m, grid[i], grid[i + 1], xtol=tol, rtol=1e-14) for i in np.flatnonzero(stable[:-1] != stable[1:])
    ]
    bounds = np.concatenate([[x_lo] if stable[0] else [], edges, [x_hi] if stable[-1] else []])
    return [(float(a), float(b)) for a, b in zip(bounds[0::2], bounds[1::2])]


def abscissa_map(family: Family2, x: np.ndarray, y: np.ndarray, *, n_nodes: int = DEFAULT_NODES) -> np.ndarray:
    """Spectral abscissa [1/s] of ``family(x_i, y_j)`` on a grid, shape (len(y), len(x)) (rows
    follow y, as ``matplotlib.pcolormesh(x, y, .)`` expects); for appendix-A.2-style maps and the
    analysis overlays. Negative cells are stable."""
    x, y = np.asarray(x, dtype=float).ravel(), np.asarray(y, dtype=float).ravel()
    out = np.empty((y.size, x.size))
    for j, yj in enumerate(y):
        for i, xi in enumerate(x):
            out[j, i] = spectral_abscissa(family(float(xi), float(yj)), n_nodes=n_nodes)
    return out
