"""Brent's method for a bracketed root of a scalar function (Brent 1973, ch. 4, procedure *zero*).

The stability bounds and the valve twin's operating point need only this one root finder; keeping
it here spares ``labrunner analyse`` and a valve campaign the ~0.2 s import of ``scipy.optimize``
(tests/test_startup_imports.py checks it is not loaded). It stops on the same criterion as ``scipy.optimize.brentq``: the
bracket's half-width below ``(xtol + rtol·|x|)/2``; tests/test_brent.py checks it against that.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from labrunner.errors import InvalidParameter

MAX_ITER = 200  # bisection alone halves a bracket of 1e3 to 1e-15 in 60 steps


def brent_root(
    f: Callable[[float], float], a: float, b: float, *, xtol: float = 2e-12, rtol: float = 4 * sys.float_info.epsilon
) -> float:
    """A root of ``f`` in [a, b], where ``f(a)`` and ``f(b)`` differ in sign (or one is zero).

    Each step takes inverse quadratic interpolation or the secant when it stays inside the bracket
    and shrinks it fast enough, else bisection, so it converges superlinearly on smooth functions
    and never slower than bisection."""
    fa, fb = float(f(a)), float(f(b))
    if fa == 0.0:
        return float(a)
    if fb == 0.0:
        return float(b)
    if (fa > 0.0) == (fb > 0.0):
        raise InvalidParameter("bracket", f"f must change sign on [{a}, {b}], got f = {fa} and {fb}")
    c, fc = a, fa
    d = e = b - a
    for _ in range(MAX_ITER):
        if abs(fc) < abs(fb):  # b is the best estimate, c the other end of the bracket
            a, b, c = b, c, b
            fa, fb, fc = fb, fc, fb
        tol = 0.5 * (xtol + rtol * abs(b))
        m = 0.5 * (c - b)
        if abs(m) <= tol or fb == 0.0:
            return float(b)
        if abs(e) < tol or abs(fa) <= abs(fb):
            d = e = m  # the last steps shrank too little: bisect
        else:
            s = fb / fa
            if a == c:  # secant
                p, q = 2.0 * m * s, 1.0 - s
            else:  # inverse quadratic interpolation through a, b, c
                q, r = fa / fc, fb / fc
                p = s * (2.0 * m * q * (q - r) - (b - a) * (r - 1.0))
                q = (q - 1.0) * (r - 1.0) * (s - 1.0)
            if p > 0.0:
                q = -q
            else:
                p = -p
            if 2.0 * p < min(3.0 * m * q - abs(tol * q), abs(e * q)):
                e, d = d, p / q
            else:
                d = e = m
        a, fa = b, fb
        b += d if abs(d) > tol else (tol if m > 0.0 else -tol)
        fb = float(f(b))
        if (fb > 0.0) == (fc > 0.0):  # keep the root between b and c
            c, fc = a, fa
            d = e = b - a
    raise RuntimeError(f"brent_root: no convergence in {MAX_ITER} steps, bracket [{b}, {c}]")
