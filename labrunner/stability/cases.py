"""The MFC error equations of thesis section 2.4 and appendix A as named cases, in physical units.

=====================  =========================================================  ================
case                   error equation (δ: estimation delay [s], r = gain/γ)        thesis
=====================  =========================================================  ================
mfc1-ultralocal        ė + r k_p e(t−δ) = 0,  gain ρ                               (2.40), (2.41)
mfc1-motor             ė + a e + r (k_p − a) e(t−δ) = 0,  gain b                   (2.45), (2.46)
mfc2-ultralocal        ë + r k_d ė(t−δ) + r k_p e(t−δ) = 0,  gain ρ                (2.52)-(2.54)
mfc2-motor             ë + a ė + r (k_d − a) ė(t−δ) + r k_p e(t−δ) = 0,  gain b    (2.57)-(2.59)
mfc2-second-order      ë + a₁ė + a₀e + r (k_d − a₁) ė(t−δ) + r (k_p − a₀) e(t−δ)    (A.15)-(A.18)
=====================  =========================================================  ================

``mfc1-motor`` with ``neutral=True`` is the neutral equation (A.11) (no approximation (2.43a)).
a < 0 (a₁ < 0) is the unstable plant of remark 2.8; the loop is stabilisable only for a·δ > −1.
Units: γ, ρ, b in the plant's input-gain unit (rad/(V s²) for the motor), a, a₁ [1/s], a₀ [1/s²],
k_p [1/s] (first order) or [1/s²] (second order), k_d [1/s].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter, check_finite, check_positive
from labrunner.stability import closed_forms as cf
from labrunner.stability.quasipoly import QuasiPolynomial
from labrunner.stability.scan import projected_intervals, stable_intervals

CASES = ("mfc1-ultralocal", "mfc1-motor", "mfc2-ultralocal", "mfc2-motor", "mfc2-second-order")
_SCAN_POINTS = 81
_EDGE = 1e-9  # normalised offset above the line κ_p = −a₀ on which the numeric k_d range is read


@dataclass(frozen=True)
class Loop:
    """A resolved case: plant ÿ + a1·ẏ + a0·y (first order: ẏ + a1·y, a1 = a of the motor), input-gain
    ratio r = gain/γ and delay δ [s]. ``k_p_of``/``k_d_of``/``d_of`` convert between physical gains
    and the normalised ones of :mod:`.closed_forms` (time in units of δ)."""

    case: str
    order: int
    a0: float
    a1: float
    ratio: float
    delay: float

    def quasi_polynomial(self, k_p: float, k_d: float | None = None, *, neutral: bool = False) -> QuasiPolynomial:
        """Characteristic function Δ*(s) of the error equation (thesis appendix A)."""
        r, d = self.ratio, self.delay
        if self.order == 1:
            if neutral:  # (A.11): B = (γ − b)/γ = 1 − r multiplies ė(t−δ) and −a e(t−δ)
                return QuasiPolynomial.from_terms(
                    {0.0: [1.0, self.a1], d: [r - 1.0, r * (k_p - self.a1) + (r - 1.0) * self.a1]}
                )
            return QuasiPolynomial.from_terms({0.0: [1.0, self.a1], d: [r * (k_p - self.a1)]})
        return QuasiPolynomial.from_terms({0.0: [1.0, self.a1, self.a0], d: [r * (k_d - self.a1), r * (k_p - self.a0)]})

    def k_p_of(self, x: float) -> float:
        """k_p of a normalised C = c·δ (first order) or P = κ_p·δ² (second order)."""
        offset = self.a0 if self.order == 2 else self.a1
        return offset + x / (self.ratio * self.delay**self.order)

    def k_d_of(self, x: float) -> float:
        return self.a1 + x / (self.ratio * self.delay)

    def d_of(self, k_d: float) -> float:
        return self.ratio * (k_d - self.a1) * self.delay


def resolve(
    case: str,
    *,
    gamma: float,
    delay: float,
    rho: float | None = None,
    a: float | None = None,
    b: float | None = None,
    a0: float | None = None,
    a1: float | None = None,
) -> Loop:
    """Validate the parameters of ``case`` and resolve them to a :class:`Loop`."""
    if case not in CASES:
        raise InvalidParameter("case", f"must be one of {', '.join(CASES)}, got {case!r}")
    gamma, delay = check_positive("gamma", gamma), check_positive("delay", delay)
    order = 1 if case.startswith("mfc1") else 2
    if case.endswith("ultralocal"):
        if rho is None and b is None:
            raise InvalidParameter("rho", f"is required for case {case} (or give b)")
        gain = check_positive("rho", rho) if rho is not None else check_positive("b", b)
        return Loop(case, order, 0.0, 0.0, gain / gamma, delay)
    b_val = check_positive("b", _required("b", b, case))
    if case == "mfc2-second-order":
        a0_val = check_finite("a0", _required("a0", a0, case), "a finite number >= 0")
        if a0_val < 0:
            raise InvalidParameter("a0", f"must be >= 0 (thesis A.6), got {a0_val}")
        return Loop(case, 2, a0_val, check_finite("a1", _required("a1", a1, case)), b_val / gamma, delay)
    return Loop(case, order, 0.0, check_finite("a", _required("a", a, case)), b_val / gamma, delay)


def check_scales(loop: Loop, k_d: float | None) -> None:
    """Refuse parameters whose normalised forms (time in units of δ) leave the range in which the
    closed forms and the solver are computed in floating point: r = gain/γ within 1e±9, δ within
    1e-9…1e6 s, and |a₁δ|, a₀δ², |r(k_d − a₁)δ| at most 1e6 (the thesis's loops are O(1)–O(100))."""
    names = ("rho" if loop.case.endswith("ultralocal") else "b", "a1" if loop.case == "mfc2-second-order" else "a")
    checks = [
        ("gamma", "gain/gamma", loop.ratio, 1e-9, 1e9),
        ("delay", "delay [s]", loop.delay, 1e-9, 1e6),
        (names[1], f"{names[1]}·delay", abs(loop.a1 * loop.delay), 0.0, 1e6),
        ("a0", "a0·delay²", loop.a0 * loop.delay * loop.delay, 0.0, 1e6),
    ]
    if k_d is not None:
        checks.append(("k_d", "gain/gamma·(k_d − a1)·delay", abs(loop.d_of(k_d)), 0.0, 1e6))
    for field, what, value, lo, hi in checks:
        if not (lo <= value <= hi) or not np.isfinite(value):
            raise InvalidParameter(
                field, f"gives {what} = {value:.3g}, outside [{lo:g}, {hi:g}] (the range these bounds are computed in)"
            )


def _required(field: str, value: float | None, case: str) -> float:
    if value is None:
        raise InvalidParameter(field, f"is required for case {case}")
    return value


def _check_k_d(loop: Loop, k_d: float | None) -> float | None:
    if loop.order == 1:
        if k_d is not None:
            raise InvalidParameter("k_d", f"is not used by the first-order case {loop.case}")
        return None
    if k_d is None:
        raise InvalidParameter("k_d", f"is required for the second-order case {loop.case}")
    return check_finite("k_d", k_d)


def _pair(interval: tuple[float, float], convert) -> list[float]:
    return [float(convert(interval[0])) + 0.0, float(convert(interval[1])) + 0.0]


def _intervals(found: list[tuple[float, float]], convert) -> list[float] | list[list[float]] | None:
    """One interval as [lo, hi]; none as None; several (A.6 plants only) as a list of them."""
    pairs = [_pair(i, convert) for i in found]
    return None if not pairs else pairs[0] if len(pairs) == 1 else pairs


def _k_p_interval(loop: Loop, k_d: float | None) -> tuple[float, float] | None:
    """Closed-form k_p interval (normalised): first order (2.46), second order at k_d."""
    if loop.order == 1:
        return cf.first_order_gain(loop.a1 * loop.delay)
    return cf.second_order_p_gain(loop.a0 * loop.delay**2, loop.a1 * loop.delay, loop.d_of(k_d))


def closed_form_bounds(loop: Loop, k_d: float | None) -> dict:
    """``{"k_p": [lo, hi] | None}`` (+ ``"k_d"`` for second order) from the corrected closed forms."""
    interval = _k_p_interval(loop, k_d)
    out = {"k_p": None if interval is None else _pair(interval, loop.k_p_of)}
    if loop.order == 2:
        out["k_d"] = _intervals(cf.second_order_d_gain(loop.a0 * loop.delay**2, loop.a1 * loop.delay), loop.k_d_of)
    return out


def numeric_bounds(loop: Loop, k_d: float | None) -> dict:
    """The same intervals from the spectral abscissa alone (:mod:`.scan`).

    The scan windows are generous multiples of the delay's natural scale (normalised units); the
    quasi-polynomials are built in physical units. The k_d range of a second-order case is the
    projection of the stable (k_d, k_p) set. For a₀ = 0 its lower edge is the line k_p = 0 (where
    the root s = 0 crosses, Δ*(0) = κ_p; the even roots' p(z_j) are negative there), so the range
    is read on that line, 1e-9 (normalised) above it; for a₀ > 0 it is found as the set where
    min over k_p of the spectral abscissa is negative (slower, :func:`.scan.projected_intervals`).
    """
    d, n = loop.delay, loop.order
    a0, a1 = loop.a0 * d**2, abs(loop.a1 * d)
    if n == 1:
        fam = lambda k: loop.quasi_polynomial(k)  # noqa: E731
        found = stable_intervals(fam, loop.k_p_of(-a1 - 2.0), loop.k_p_of(a1 + 2 * np.pi), n_scan=_SCAN_POINTS)
        return {"k_p": _intervals(found, float)}
    p_lo, p_hi = loop.k_p_of(-a0 - 2.0), loop.k_p_of(a0 + 2 * np.pi * a1 + 4 * np.pi**2)
    d_lo, d_hi = loop.k_d_of(-a1 - a0 - 2.0), loop.k_d_of(a1 + a0 + 2 * np.pi)
    fam_p = lambda k: loop.quasi_polynomial(k, k_d)  # noqa: E731
    found_p = stable_intervals(fam_p, p_lo, p_hi, n_scan=_SCAN_POINTS)
    if loop.a0 == 0.0:
        edge = loop.k_p_of(_EDGE)
        found_d = stable_intervals(lambda k: loop.quasi_polynomial(edge, k), d_lo, d_hi, n_scan=_SCAN_POINTS)
    else:
        found_d = projected_intervals(
            lambda kd, kp: loop.quasi_polynomial(kp, kd), d_lo, d_hi, p_lo, p_hi, n_x=21, n_y=31
        )
    return {"k_p": _intervals(found_p, float), "k_d": _intervals(found_d, float)}


def bounds(
    case: str,
    *,
    gamma: float,
    delay: float,
    rho: float | None = None,
    a: float | None = None,
    b: float | None = None,
    k_d: float | None = None,
    a0: float | None = None,
    a1: float | None = None,
    numeric: bool = False,
) -> dict:
    """Stability intervals of ``case`` (open intervals), exactly the object ``labrunner bounds --json``
    prints: ``{"k_p": [lo, hi] | None}``, plus ``"k_d": [lo, hi] | None`` for second-order cases
    (k_p at the given ``k_d``; None when no k_p is stable there), plus ``"numeric"`` (the same keys
    from the spectral-abscissa solver) when ``numeric``. See the module table for the cases;
    ``a0``, ``a1`` belong to ``mfc2-second-order``, ``rho`` defaults to ``b`` for the ultra-local
    cases. A k_d range made of several intervals (A.6 plants with a₀δ² ≳ 1 only) is a list of
    [lo, hi] pairs; so is a numeric range that comes out in pieces."""
    loop = resolve(case, gamma=gamma, delay=delay, rho=rho, a=a, b=b, a0=a0, a1=a1)
    k_d = _check_k_d(loop, k_d)
    check_scales(loop, k_d)
    out = closed_form_bounds(loop, k_d)
    if numeric:
        out["numeric"] = numeric_bounds(loop, k_d)
    return out


def case_quasipolynomial(
    case: str,
    *,
    gamma: float,
    delay: float,
    k_p: float,
    k_d: float | None = None,
    rho: float | None = None,
    a: float | None = None,
    b: float | None = None,
    a0: float | None = None,
    a1: float | None = None,
    neutral: bool = False,
) -> QuasiPolynomial:
    """Characteristic quasi-polynomial of ``case`` at one parameter point, e.g. for
    ``abscissa_map(lambda g, kp: case_quasipolynomial("mfc1-motor", gamma=g, k_p=kp, ...), g, kp)``.
    ``neutral=True`` (case mfc1-motor only) gives the neutral equation (A.11)."""
    loop = resolve(case, gamma=gamma, delay=delay, rho=rho, a=a, b=b, a0=a0, a1=a1)
    if neutral and case != "mfc1-motor":
        raise InvalidParameter("neutral", f"only case mfc1-motor has a neutral form (thesis (A.11)), got {case}")
    return loop.quasi_polynomial(check_finite("k_p", k_p), _check_k_d(loop, k_d), neutral=neutral)


def predict_stable(
    case: str,
    *,
    gamma,
    k_p,
    delay,
    k_d=None,
    rho: float | None = None,
    a: float | None = None,
    b: float | None = None,
    a0: float | None = None,
    a1: float | None = None,
):
    """Whether the closed forms predict an exponentially stable error equation at each point.

    ``gamma``, ``k_p``, ``delay`` and ``k_d`` broadcast like numpy arrays; returns a bool array of
    the broadcast shape (a plain bool when all are scalars). Each distinct (γ, δ, k_d) costs one
    closed-form evaluation; k_p is then compared in bulk.
    """
    kd_in = 0.0 if k_d is None else k_d
    g, kp, dl, kd = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (gamma, k_p, delay, kd_in)))
    out = np.zeros(g.shape, dtype=bool)
    keys = np.stack([g.ravel(), dl.ravel(), kd.ravel()], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    flat_kp, flat_out = kp.ravel(), out.reshape(-1)
    for idx, (gi, di, kdi) in enumerate(uniq):
        loop = resolve(case, gamma=gi, delay=di, rho=rho, a=a, b=b, a0=a0, a1=a1)
        interval = _k_p_interval(loop, _check_k_d(loop, None if k_d is None else kdi))
        if interval is not None:
            lo, hi = loop.k_p_of(interval[0]), loop.k_p_of(interval[1])
            sel = inverse.ravel() == idx
            flat_out[sel] = (flat_kp[sel] > lo) & (flat_kp[sel] < hi)
    return bool(out) if out.ndim == 0 else out
