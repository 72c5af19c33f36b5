"""The numerical solver of labrunner.stability against analytic references: Lambert W for
ė = −K e(t−δ), exact root chains of a factorised neutral equation, polynomial roots."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import lambertw

from labrunner.errors import InvalidParameter
from labrunner.stability import (
    QuasiPolynomial,
    abscissa_map,
    difference_abscissa,
    gain_boundaries,
    rightmost_roots,
    spectral_abscissa,
    stable_intervals,
)


def scalar(k: float, delay: float) -> QuasiPolynomial:
    """Δ(s) = s + k·exp(−sδ)."""
    return QuasiPolynomial.from_terms({0.0: [1.0, 0.0], delay: [k]})


@pytest.mark.parametrize("k_delta", [1e-3, 0.2, 0.36, 1.0, np.pi / 2, 2.0, 10.0, 300.0])
@pytest.mark.parametrize("delay", [0.01, 0.035, 1.0])
def test_scalar_rightmost_root_is_principal_lambert_w(k_delta, delay):
    # s = W_0(−Kδ)/δ is the rightmost root of s + K e^{−sδ} (Shinozaki & Mori 2006)
    expected = complex(lambertw(-k_delta, 0)) / delay
    root = rightmost_roots(scalar(k_delta / delay, delay), 1)[0]
    assert abs(root - complex(expected.real, abs(expected.imag))) <= 1e-10 * abs(expected)
    assert spectral_abscissa(scalar(k_delta / delay, delay)) == pytest.approx(
        expected.real, rel=1e-10, abs=1e-12 / delay
    )


def test_further_roots_are_the_other_lambert_branches():
    roots = rightmost_roots(scalar(1.0, 1.0), 4)
    expected = [complex(lambertw(-1.0, k)) for k in (0, 1, 2, 3)]
    expected = [complex(e.real, abs(e.imag)) for e in expected]
    np.testing.assert_allclose(roots, expected, rtol=1e-10)


def test_scalar_boundary_is_pi_over_two():
    # thesis (2.41) with ρ/γ = 1, δ = 1: stable iff 0 < k < π/2
    b = gain_boundaries(lambda k: scalar(k, 1.0), -1.0, 3.0, n_scan=41)
    np.testing.assert_allclose(b, [0.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(
        stable_intervals(lambda k: scalar(k, 1.0), -1.0, 3.0, n_scan=41), [(0.0, np.pi / 2)], atol=1e-12
    )


@pytest.mark.parametrize(
    ("b", "c", "tau"), [(0.5, 1.0, 1.0), (0.5, 0.3, 1.0), (2.0, 1.0, 0.05), (-0.5, 0.3, 2.0), (0.9, 5.0, 1.0)]
)
def test_neutral_factorised_abscissa(b, c, tau):
    # (1 − b e^{−sτ})(s + c): roots −c and (ln|b| + i(2πk + arg b))/τ, so α = max(−c, ln|b|/τ)
    qp = QuasiPolynomial.from_terms({0.0: [1.0, c], tau: [-b, -b * c]})
    assert qp.is_neutral
    assert difference_abscissa(qp) == pytest.approx(np.log(abs(b)) / tau, rel=1e-14)
    assert spectral_abscissa(qp) == pytest.approx(max(-c, np.log(abs(b)) / tau), rel=1e-10)
    roots = rightmost_roots(qp, 4)
    assert np.all(np.isclose(roots, -c, rtol=1e-9) | (np.abs(b * np.exp(-roots * tau) - 1.0) < 1e-9))


def test_roots_are_genuine_and_sorted():
    qp = QuasiPolynomial.from_terms({0.0: [1.0, 2.0, 5.0], 0.3: [1.5, 40.0], 0.7: [-3.0]})
    roots = rightmost_roots(qp, 6)
    value, _, size = qp.evaluate(roots)
    assert np.all(np.abs(value) <= 1e-11 * size)
    assert np.all(np.diff(roots.real) <= 0) and np.all(roots.imag >= 0)


def test_collocation_size_does_not_change_the_answer():
    qp = QuasiPolynomial.from_terms({0.0: [1.0, 39.44, 0.0], 0.035: [20.0, 700.0]})
    assert spectral_abscissa(qp, n_nodes=16) == pytest.approx(spectral_abscissa(qp, n_nodes=40), rel=1e-12)


def test_derivative_matches_finite_difference():
    qp = QuasiPolynomial.from_terms({0.0: [2.0, 1.0, 3.0], 0.5: [0.7, -1.0, 2.0]})
    s = np.array([0.3 + 1.2j, -1.0 + 4.0j])
    h = 1e-6
    fd = (qp.evaluate(s + h)[0] - qp.evaluate(s - h)[0]) / (2 * h)
    np.testing.assert_allclose(qp.evaluate(s)[1], fd, rtol=1e-8)


def test_polynomial_without_delay():
    qp = QuasiPolynomial.from_terms({0.0: [1.0, 3.0, 2.0]})
    assert spectral_abscissa(qp) == pytest.approx(-1.0)


def test_from_terms_pads_rows():
    qp = QuasiPolynomial.from_terms({0.2: [5.0], 0.0: [1.0, 2.0]})
    np.testing.assert_array_equal(qp.coeffs, [[1.0, 2.0], [0.0, 5.0]])
    np.testing.assert_array_equal(qp.delays, [0.0, 0.2])


@pytest.mark.parametrize(
    ("coeffs", "delays"),
    [
        ([[0.0, 1.0], [0.0, 1.0]], [0.0, 1.0]),  # no undelayed s^n term
        ([[1.0, 1.0], [0.0, 1.0]], [0.1, 1.0]),  # first delay not 0
        ([[1.0, 1.0], [0.0, 1.0]], [0.0, 0.0]),  # repeated delay
        ([[1.0, np.nan], [0.0, 1.0]], [0.0, 1.0]),
        ([[1.0], [1.0]], [0.0, 1.0]),
    ],  # degree 0
)
def test_invalid_quasipolynomial(coeffs, delays):
    with pytest.raises(InvalidParameter):
        QuasiPolynomial(np.array(coeffs), np.array(delays))


def test_two_neutral_delays_are_refused():
    qp = QuasiPolynomial.from_terms({0.0: [1.0, 1.0], 0.5: [0.2, 0.0], 1.0: [0.1, 0.0]})
    with pytest.raises(InvalidParameter, match="one delay"):
        spectral_abscissa(qp)


def test_scan_finds_a_dip_between_samples():
    # α(k) = 100 (k − 0.503)² − 1e-4 < 0 only on (0.502, 0.504), inside one scan cell
    def fam(k):
        return QuasiPolynomial.from_terms({0.0: [1.0, 1e-4 - 100 * (k - 0.503) ** 2], 1.0: [0.0]})

    np.testing.assert_allclose(gain_boundaries(fam, 0.0, 1.0, n_scan=11), [0.502, 0.504], atol=1e-9)


def test_gain_window_is_validated():
    with pytest.raises(InvalidParameter):
        gain_boundaries(lambda k: scalar(k, 1.0), 1.0, 1.0)


def test_abscissa_map_orientation():
    x = np.array([0.5, 2.0, 3.0])  # k
    y = np.array([1.0, 0.5])  # delay
    m = abscissa_map(lambda k, d: scalar(k, d), x, y)
    assert m.shape == (2, 3)
    expected = [[complex(lambertw(-k * d)).real / d for k in x] for d in y]
    np.testing.assert_allclose(m, expected, rtol=1e-10)


def test_abscissa_falls_back_to_collocation_when_newton_rejects_all(monkeypatch):
    from labrunner.stability import spectrum

    monkeypatch.setattr(spectrum, "_newton", lambda q, start: start[:0])
    expected = complex(lambertw(-2.0)).real  # unstable: must not turn into −inf
    assert spectral_abscissa(scalar(2.0, 1.0)) == pytest.approx(expected, rel=1e-6)
    assert rightmost_roots(scalar(2.0, 1.0)).size == 0
