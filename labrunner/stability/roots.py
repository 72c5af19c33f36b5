"""Real roots of the transcendental equations of thesis appendix A, in ascending order.

Between two consecutive turning points (roots of h') a function is monotone and holds at most one
root, which its end values bracket. So: find the turning points of h on (0, z_max] from sign
changes of h' on a grid finer than the oscillation (h' refined by Brent's method), then bracket
one root per monotone segment. z = 0 is never reported: the root z_0 = 0 of Δ_Im is implicit and
the first positive root is z_1.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from labrunner.brent import brent_root

Fn = Callable[[np.ndarray], np.ndarray]

GRID_STEP = np.pi / 64  # h' oscillates with period 2π in z; 128 samples per period
_XTOL = 1e-15


def _sign_changes(f: Fn, grid: np.ndarray) -> list[float]:
    values = f(grid)
    out: list[float] = []
    for i in np.flatnonzero(np.sign(values[:-1]) * np.sign(values[1:]) < 0):
        out.append(brent_root(lambda z: float(f(np.array(z))), grid[i], grid[i + 1], xtol=_XTOL, rtol=1e-15))
    out.extend(float(z) for z in grid[1:-1][values[1:-1] == 0.0])
    return sorted(out)


def turning_points(dh: Fn, z_max: float) -> list[float]:
    """Roots of h' on (0, z_max), ascending."""
    grid = np.linspace(0.0, z_max, int(np.ceil(z_max / GRID_STEP)) + 1)
    return _sign_changes(dh, grid)


def roots_between(h: Fn, ends: np.ndarray, h_at: Callable[[float], float] | None = None) -> np.ndarray:
    """One root per monotone segment [ends[i], ends[i+1]] where h changes sign, ascending. ``h_at``: h of
    one float, the same numbers faster, for Brent's steps (default: h of a 0-d array)."""
    values = h(np.asarray(ends, dtype=float))
    at = h_at or (lambda z: float(h(np.array(z))))
    roots: list[float] = []
    for i in range(len(ends) - 1):
        if values[i] * values[i + 1] < 0.0:
            roots.append(brent_root(at, ends[i], ends[i + 1], xtol=_XTOL, rtol=1e-15))
        elif values[i + 1] == 0.0 and ends[i + 1] > 0.0:
            roots.append(float(ends[i + 1]))
    return np.array(roots)


def ascending_roots(h: Fn, dh: Fn, z_max: float) -> np.ndarray:
    """Every simple root z ∈ (0, z_max] of h, ascending (h, dh vectorised; h regular at 0)."""
    return roots_between(h, np.array([0.0, *turning_points(dh, z_max), z_max]))


def sinc(z: np.ndarray) -> np.ndarray:
    """sin(z)/z, regular at 0."""
    return np.sinc(np.asarray(z) / np.pi)


def dsinc(z: np.ndarray) -> np.ndarray:
    """d/dz sin(z)/z = (z cos z − sin z)/z², regular at 0 (series below |z| = 1e-4)."""
    z = np.asarray(z, dtype=float)
    small = np.abs(z) < 1e-4
    zs = np.where(small, 1.0, z)
    return np.where(small, -z / 3.0, (zs * np.cos(zs) - np.sin(zs)) / zs**2)


def first_order_crossing(a_delta: float) -> float | None:
    """z̃ ∈ (0, π): the root of tan z = −z/(a·δ) (thesis (2.46); Silva et al. 2000) that sets the
    upper gain bound of s + a + c·e^{−sδ}. In (π/2, π) for aδ > 0, π/2 for aδ = 0, (0, π/2) for
    −1 < aδ < 0 (remark 2.8, unstable plant). None for aδ ≤ −1: no gain stabilises the loop.

    Solved as z cos z + aδ sin z = 0, divided by z: cos z + aδ·sinc z = 0.
    """
    if a_delta <= -1.0:
        return None
    roots = ascending_roots(
        lambda z: np.cos(z) + a_delta * sinc(z),
        lambda z: -np.sin(z) + a_delta * dsinc(z),
        np.pi,
    )
    return float(roots[0])
