"""Closed-form gain bounds of thesis section 2.4 and appendix A, corrected where the thesis is wrong,
in normalised (dimensionless) gains: time in units of the delay δ.

First order (thesis (2.41), (2.45)/(2.46), remark 2.8): Δ(s) = s + a + c·e^{−sδ}, with
A = a·δ and C = c·δ. Hayes' theorem (Silva et al. 2000, Sec. 3): stable iff A > −1 and
−A < C < sqrt(z̃² + A²), z̃ from :func:`~labrunner.stability.roots.first_order_crossing`.

Second order (appendix A.6, which contains A.4 for a₀ = a₁ = 0 and A.5 / (2.57) for a₀ = 0, a₁ = a):
Δ(s) = (s² + a₁s + a₀)e^{sδ} + κ_d s + κ_p, normalised A0 = a₀δ², A1 = a₁δ, D = κ_d δ, P = κ_p δ².
On s = i z/δ the imaginary part vanishes at z_0 = 0 and where d(z) = D, the real part is P − p(z):

    d(z) = z sin z − A0 sin z / z − A1 cos z,        p(z) = (z² − A0) cos z + A1 z sin z.

Hermite–Biehler interlacing (appendix A, Theorem 1) asks Δ_Re(z_j) to alternate in sign starting
positive at z_0: P > p(z_j) for even j (z_0 gives P > −A0) and P < p(z_j) for odd j. Both the even
and the odd conditions are kept. The D interval is where that P interval is non-empty: from
D > −A1 − A0 (Condition 2 at ω = 0) up to the corner z* where the first crossing curve (d(z), p(z))
meets the line P = −A0, i.e. the first positive root of p(z) + A0 = 0, D_max = d(z*).

The thesis bounds D by the tangency of the two sides of d(z) = D instead ((2.53), and the
tangency of appendix A.6). That is only necessary: between d(z*) and the tangency value the roots
are real but z_1 lies beyond z*, p(z_1) < −A0, and no P is stable. For A.4 this gives the corner
z* = π/2 and D_max = π/2, not z̃ sin z̃ ≈ 1.8197; for A.5 it gives tan z* = −z*/(a δ) and
D_max = sqrt(z*² + (aδ)²), which is (2.58) as printed.
"""

from __future__ import annotations

import numpy as np

from labrunner.stability.roots import ascending_roots, dsinc, first_order_crossing, sinc

Interval = tuple[float, float]


def first_order_gain(a_delta: float) -> Interval | None:
    """Interval of C = c·δ for which s + a + c·e^{−sδ} is stable (thesis (2.46), remark 2.8)."""
    z = first_order_crossing(a_delta)
    if z is None:
        return None
    return -a_delta, float(np.hypot(z, a_delta))


def crossing_d(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    """d(z): the D at which Δ_Im(z) = 0 (normalised A0, A1)."""
    return z * np.sin(z) - a0 * sinc(z) - a1 * np.cos(z)


def _crossing_dd(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    return np.sin(z) + z * np.cos(z) - a0 * dsinc(z) + a1 * np.sin(z)


def crossing_p(z: np.ndarray, a0: float, a1: float) -> np.ndarray:
    """p(z): the P at which Δ_Re(z) = 0 (normalised A0, A1)."""
    return (z**2 - a0) * np.cos(z) + a1 * z * np.sin(z)


def _search_span(a0: float, a1: float, d: float = 0.0) -> float:
    """Beyond this z the roots of d(z) = D sit next to multiples of π with |p| ~ z² ≫ A0, A1 z:
    odd roots give large positive upper bounds and even ones large negative lower bounds, so
    they never bind."""
    return 8.0 * np.pi + np.sqrt(abs(a0)) + abs(a1) + abs(d)


def corner(a0: float, a1: float) -> float | None:
    """z*: the first positive root of p(z) + A0 = 0 (the crossing curve meets P = −A0)."""
    roots = ascending_roots(
        lambda z: crossing_p(z, a0, a1) + a0,
        lambda z: 2 * z * np.cos(z) - (z**2 - a0) * np.sin(z) + a1 * (np.sin(z) + z * np.cos(z)),
        _search_span(a0, a1),
    )
    return float(roots[0]) if roots.size else None


def second_order_d_gain(a0: float, a1: float) -> Interval | None:
    """Interval of D = κ_d·δ for which some P stabilises (corrected (2.53), (2.58), A.6)."""
    z = corner(a0, a1)
    if z is None:
        return None
    lo, hi = -a1 - a0, float(crossing_d(np.array(z), a0, a1))
    return (lo, hi) if hi > lo else None


def imaginary_roots(a0: float, a1: float, d: float) -> np.ndarray:
    """z_1 < z_2 < ...: the positive roots of Δ_Im, i.e. of d(z) = D (thesis (A.13), (2.59))."""
    return ascending_roots(
        lambda z: crossing_d(z, a0, a1) - d,
        lambda z: _crossing_dd(z, a0, a1),
        _search_span(a0, a1, d),
    )


def second_order_p_gain(a0: float, a1: float, d: float) -> Interval | None:
    """Interval of P = κ_p·δ² for which Δ is stable at D = κ_d·δ (corrected (2.54), (2.59), A.6);
    None when D is outside :func:`second_order_d_gain` or the interlacing interval is empty."""
    d_range = second_order_d_gain(a0, a1)
    if d_range is None or not d_range[0] < d < d_range[1]:
        return None
    z = imaginary_roots(a0, a1, d)
    p = crossing_p(z, a0, a1)
    lo = max(-a0, float(np.max(p[1::2], initial=-np.inf)))   # z_2, z_4, ...: Δ_Re > 0
    hi = float(np.min(p[0::2], initial=np.inf))              # z_1, z_3, ...: Δ_Re < 0
    return (lo, hi) if lo < hi else None
