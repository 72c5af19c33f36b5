"""Stability of MFC loops with estimation delay: corrected closed-form gain bounds (thesis section
2.4, appendix A) and an independent numerical solver (spectral abscissa of delay equations by
Chebyshev collocation of the infinitesimal generator, Breda–Maset–Vermiglio, plus Newton).

Public API::

    bounds(case, *, gamma, delay, rho=None, a=None, b=None, k_d=None, a0=None, a1=None, numeric=False) -> dict
    predict_stable(case, *, gamma, k_p, delay, k_d=None, rho=None, a=None, b=None, a0=None, a1=None) -> bool | ndarray
    case_quasipolynomial(case, *, gamma, delay, k_p, k_d=None, ..., neutral=False) -> QuasiPolynomial
    QuasiPolynomial(coeffs, delays), QuasiPolynomial.from_terms({delay_s: [coeffs, highest power first]})
    rightmost_roots(qp, count=6, *, n_nodes=24) -> complex ndarray [1/s]
    spectral_abscissa(qp, *, n_nodes=24) -> float [1/s]
    gain_boundaries(family, lo, hi, *, n_scan=101) -> ndarray;  stable_intervals(...) -> list[(lo, hi)]
    projected_intervals(family2, x_lo, x_hi, y_lo, y_hi) -> list[(lo, hi)]   # x for which some y is stable
    abscissa_map(family2, x, y) -> ndarray (len(y), len(x))
"""

from labrunner.stability.cases import CASES, bounds, case_quasipolynomial, predict_stable, resolve
from labrunner.stability.quasipoly import QuasiPolynomial
from labrunner.stability.scan import abscissa_map, gain_boundaries, projected_intervals, stable_intervals
from labrunner.stability.spectrum import difference_abscissa, rightmost_roots, spectral_abscissa

__all__ = [
    "CASES",
    "QuasiPolynomial",
    "abscissa_map",
    "bounds",
    "case_quasipolynomial",
    "difference_abscissa",
    "gain_boundaries",
    "predict_stable",
    "projected_intervals",
    "resolve",
    "rightmost_roots",
    "spectral_abscissa",
    "stable_intervals",
]
