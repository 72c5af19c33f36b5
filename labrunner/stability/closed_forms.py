"""Closed-form gain bounds of thesis section 2.4 and appendix A, corrected where the thesis is wrong,
in normalised (dimensionless) gains: time in units of the delay δ.

First order (thesis (2.41), (2.45)/(2.46), remark 2.8): Δ(s) = s + a + c·e^{−sδ}, with
A = a·δ and C = c·δ. Hayes' theorem (Silva et al. 2000, Sec. 3): stable iff A > −1 and
−A < C < sqrt(z̃² + A²), z̃ from :func:`~labrunner.stability.roots.first_order_crossing`.

Second order (appendix A.6, which contains A.4 for a₀ = a₁ = 0 and A.5 / (2.57) for a₀ = 0, a₁ = a):
Δ(s) = (s² + a₁s + a₀)e^{sδ} + κ_d s + κ_p, normalised A0 = a₀δ², A1 = a₁δ, D = κ_d δ, P = κ_p δ².
On s = i z/δ the imaginary part vanishes at z_0 = 0 and where d(z) = D, the real part is P − p(z):

    d(z) = z sin z − A0 sin z / z − A1 cos z,        p(z) = (z² − A0) cos z + A1 z sin z.

Theorem 1 of appendix A (Silva et al.'s generalised Hermite–Biehler theorem) with ω₀ = 0, made
complete:

1. Condition 2 at ω₀ = 0: (A0 + P)(A1 + A0 + D) > 0; P > −A0 is necessary anyway (Δ(0) = a₀ + κ_p
   must be positive), so D > −A1 − A0.
2. Δ_Im has only real roots (Theorem 2, η = π/4): on (0, 2Lπ − π/4] it has exactly 2L positive roots
   once L is large enough that every root beyond the first few sits next to a multiple of π.
3. Interlacing: Δ_Re(z_j) alternates in sign starting positive at z_0, i.e. P > p(z_j) for even j
   (z_0 gives P > −A0) and P < p(z_j) for odd j. Both the even and the odd conditions are kept.

The D interval is where these leave a non-empty P interval. The count (2.) changes only where D
passes a turning value of d(z), and between two such values the P interval's width varies
continuously, so the D edges are D = −A1 − A0, turning values of d, or zeros of that width, which
Brent's method refines.

The thesis bounds D by the tangency of the two sides of d(z) = D instead ((2.53), and the tangency
of appendix A.6) and by Condition 2 alone. Those are only necessary: for A.4 the width vanishes at
z_1 = π/2, so D_max = π/2 and not z̃ sin z̃ ≈ 1.8197 (between the two the roots are real but
p(z_1) < 0); for A.5 it vanishes where tan z_1 = −z_1/(aδ), D_max = sqrt(z_1² + (aδ)²), which is
(2.58) as printed. For A.6 with a₀δ² of order one (plant period comparable to δ) the count fails
well inside (−A1 − A0, tangency): the k_d interval shrinks on both sides.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from labrunner.brent import brent_root
from labrunner.stability.roots import dsinc, first_order_crossing, roots_between, sinc, turning_points

Interval = tuple[float, float]


@lru_cache(maxsize=4096)
def first_order_gain(a_delta: float) -> Interval | None:
    """Interval of C = c·δ for which s + a + c·e^{−sδ} is stable (thesis (2.46), remark 2.8).
    Cached: in these normalised units it does not depend on γ, so a γ–k_p map needs it once."""
    z = first_order_crossing(a_delta)
    if z is None:
        return None
    return -a_delta, float(np.hypot(z, a_delta))


def crossing_d(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    """d(z): the D at which Δ_Im(z) = 0 (normalised A0, A1)."""
    return z * np.sin(z) - a0 * sinc(z) - a1 * np.cos(z)


_SINC_AT_0 = float(np.finfo(float).eps)  #: where np.sinc evaluates sin(y)/y at y = 0


def _crossing_d_at(z: float, a0: float, a1: float) -> float:
    """:func:`crossing_d` of one float, with the same operations on floats (np.sinc's included): Brent's
    method calls it for every step of every root, and on a 0-d array numpy took 7.4 µs a call against
    0.23 µs here. Equal to it bit for bit (tests/test_stability_bounds.py)."""
    y = math.pi * (z / math.pi)
    y = y if y else _SINC_AT_0
    return z * math.sin(z) - a0 * (math.sin(y) / y) - a1 * math.cos(z)


def _crossing_dd(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    return np.sin(z) + z * np.cos(z) - a0 * dsinc(z) + a1 * np.sin(z)


def crossing_p(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    """p(z): the P at which Δ_Re(z) = 0 (normalised A0, A1)."""
    return (z**2 - a0) * np.cos(z) + a1 * z * np.sin(z)


_SAMPLES = 32  # width samples per D segment


@lru_cache(maxsize=512)
def _skeleton(a0: float, a1: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Ends of the monotone pieces of d on (0, Z] (0, turning points, Z), d at them, and L with
    Z = 2Lπ − π/4. Beyond z ≈ A0 + |A1| + |D| each root of d(z) = D sits next to a multiple of π and
    |p| ~ z² ≫ A0, A1 z, so later roots neither change the count's verdict nor bind P; Z leaves
    room for every D up to the turning values on (0, Z/2), where the D interval is searched."""
    reach = 3.0 * (a0 + abs(a1)) + 20.0 * np.pi
    n_periods = int(np.ceil((reach + np.pi / 4) / (2 * np.pi)))
    z_max = 2 * np.pi * n_periods - np.pi / 4
    ends = np.array([0.0, *turning_points(lambda z: _crossing_dd(z, a0, a1), z_max), z_max])
    return ends, crossing_d(ends, a0, a1), n_periods


def _binding_span(a0: float, a1: float, d: float) -> float:
    """Roots beyond this z sit within ~(A0 + |A1| + |D|)/z of a multiple of π, where
    |p| ≥ z² − A0 − |A1| z ≫ every bound of the first roots: they cannot bind P."""
    return 4.0 * np.pi + 2.0 * (np.sqrt(a0) + abs(a1) + abs(d))


def _p_window(a0: float, a1: float, d: float) -> tuple[float, float] | None:
    """(lower, upper) P bounds from interlacing at D, or None when the roots of Δ_Im are not all
    real (count condition 2.)."""
    ends, values, n_periods = _skeleton(a0, a1)
    if np.count_nonzero((values[:-1] - d) * (values[1:] - d) < 0) != 2 * n_periods:
        return None
    near = ends[: int(np.searchsorted(ends, _binding_span(a0, a1, d))) + 1]
    z = roots_between(lambda x: crossing_d(x, a0, a1) - d, near, lambda x: _crossing_d_at(x, a0, a1) - d)
    p = crossing_p(z, a0, a1)
    lo = max(-a0, float(np.max(p[1::2], initial=-np.inf)))  # z_2, z_4, ...: Δ_Re > 0
    hi = float(np.min(p[0::2], initial=np.inf))  # z_1, z_3, ...: Δ_Re < 0
    return lo + 0.0, hi


@lru_cache(maxsize=4096)
def second_order_p_gain(a0: float, a1: float, d: float) -> Interval | None:
    """Interval of P = κ_p·δ² for which Δ is stable at D = κ_d·δ (corrected (2.54), (2.59), A.6);
    None when no P is. Cached: the maps, the agreement and the report ask for the same D."""
    if not d > -a1 - a0:
        return None
    window = _p_window(a0, a1, d)
    return window if window is not None and window[0] < window[1] else None


def _width(a0: float, a1: float, d: float) -> float:
    window = _p_window(a0, a1, d)
    return -np.inf if window is None else window[1] - window[0]


@lru_cache(maxsize=512)
def second_order_d_gain(a0: float, a1: float) -> tuple[Interval, ...]:
    """Intervals of D = κ_d·δ for which some P stabilises (corrected (2.53), (2.58), A.6), ascending;
    one interval for the thesis's plants (a₀ = 0). Cached: it depends on the plant and δ only, and
    map overlays ask for it once per γ or k_d sample."""
    ends, values, _ = _skeleton(a0, a1)
    d_min = -a1 - a0
    inner = values[1:-1][ends[1:-1] <= ends[-1] / 2]
    breaks = np.unique(np.concatenate([[d_min], inner[inner > d_min]]))
    width = lambda x: _width(a0, a1, x)  # noqa: E731
    found: list[list[float]] = []
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        if not np.isfinite(width(0.5 * (lo + hi))):  # the count is constant on (lo, hi)
            continue
        xs = lo + (hi - lo) * np.concatenate([[1e-12], np.linspace(0.0, 1.0, _SAMPLES)[1:-1], [1.0 - 1e-12]])
        positive = np.array([width(x) for x in xs]) > 0
        for i0, i1 in _runs(positive):
            left = lo if i0 == 0 else brent_root(width, xs[i0 - 1], xs[i0], xtol=1e-15, rtol=1e-15)
            right = hi if i1 == len(xs) - 1 else brent_root(width, xs[i1], xs[i1 + 1], xtol=1e-15, rtol=1e-15)
            if found and found[-1][1] == left:
                found[-1][1] = right
            else:
                found.append([left, right])
    return tuple((float(a), float(b)) for a, b in found)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) indices of each run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))
