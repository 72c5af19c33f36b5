"""AlgDiff (PyPI ``algdiff``, Othmane 2022a) as a test-only oracle for labrunner.differentiators.

The library never imports AlgDiff. Where we differ on purpose the test says why:
- AlgDiff takes L = int(T/t_s), which drops a tap when T/t_s rounds below n_s (n_s = 29 at 200 Hz);
  we carry n_s as an integer. The sweep skips those designs after asserting the dropped tap.
- its default 'same' convolution adds one sample of delay for even filter lengths; ours is causal.
- its cutoff computation overflows from α ≈ 100; we use log-gamma.
- its trapezoidal and analytic weights evaluate the kernel at j·t_s instead of j·T/n_s, which
  matters where the kernel has an infinite slope at the window end (see the sweep), and its analytic order-0 ones turn NaN when the last edge (i+1)·t_s/T rounds above 1.
- for trapezoidal weights whose kernel is infinite at the window ends (min(α, β) < n) it silently
  puts 0 there; we refuse the design (InvalidParameter).
- its spectra set mpmath's global precision to 150 digits; the fixture below restores it.
- its Simpson, 3/8 and Boole variants place L nodes on linspace(0, T, L) with L rounded up to a
  multiple of the rule's order, i.e. not at multiples of t_s, so they do not form an FIR over the
  sampled signal; we offer mid-point, trapezoidal and analytic only (InvalidParameter otherwise).
"""

from __future__ import annotations

import itertools
import math
import warnings

import mpmath
import numpy as np
import pytest
from AlgDiff import AlgebraicDifferentiator

from labrunner.differentiators import design, estimate
from labrunner.differentiators.spectra import continuous_response, cost_db, discrete_response
from labrunner.errors import InvalidParameter

ALGDIFF_METHOD = {"midpoint": "mid-point", "trapezoidal": "trapezoidal", "analytic": "analytic"}


@pytest.fixture(autouse=True)
def _algdiff_side_effects(monkeypatch):
    """AlgDiff 2.4 calls np.trapz (gone in NumPy 2) and sets mpmath's global precision."""
    monkeypatch.setattr(np, "trapz", np.trapezoid, raising=False)
    dps = mpmath.mp.dps
    yield
    mpmath.mp.dps = dps


def oracle(alpha, beta, N, fs, n_s):
    return AlgebraicDifferentiator(ts=1 / fs, alpha=alpha, beta=beta, N=N, T=n_s / fs, display=False)


def exact_node_weights(o, method: str, n: int, n_s: int, fs: float, beta: float) -> np.ndarray:
    """AlgDiff's kernel (evalKernelDer) at τ = j·T/n_s with its trapezoidal/analytic rule and Φ_n.

    At τ = T its ν = 1 − 2τ/T rounds to −1 + 2e-16, so the limit there, 0 for (T−τ)^e with e > 0,
    is put in explicitly (at τ = 0, ν = 1 is exact).
    """
    k = n if method == "trapezoidal" else n - 1
    values = o.evalKernelDer(np.arange(n_s + 1) / n_s * (n_s / fs), k)
    if beta - k > 0:
        values[-1] = 0.0
    if method == "trapezoidal":
        raw = values / fs
        raw[[0, -1]] /= 2
    else:
        raw = np.diff(values)
    return raw / (np.dot(raw, (-np.arange(raw.size) / fs) ** n) / math.factorial(n))


# (α, β) from 1 to 20, integer and not, α = β and α ≠ β; each paired with sampling rates and windows.
PAIRS = [(1, 1), (1, 3.5), (2, 2), (2.5, 7.25), (4, 1.5), (6, 6), (9.7, 12), (20, 20), (13, 1.2), (1.5, 2)]
RATES = [20.0, 200.0, 1000.0, 4000.0, 32000.0]
WINDOWS = [10, 17, 29, 64, 131]  # n_s
SWEEP = [
    (a, b, N, fs, WINDOWS[(i + k) % len(WINDOWS)])
    for i, (a, b) in enumerate(PAIRS)
    for k, (fs, N) in enumerate(zip(RATES, itertools.cycle([0, 1, 2, 0, 1])))
]


def test_sweep_weights_match_algdiff():
    """Mid-point, trapezoidal and analytic coefficients for orders 0-2 agree to 1e-10 (relative to
    the largest coefficient), with cutoff, ϑ and delays, wherever AlgDiff keeps all n_s samples."""
    compared = dropped = 0
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # AlgDiff's aliasing hint for short windows
        for alpha, beta, N, fs, n_s in SWEEP:
            o = oracle(alpha, beta, N, fs, n_s)
            if int(o.get_T() / o.get_ts()) != n_s:  # AlgDiff's float truncation drops the last tap
                assert int(o.get_T() / o.get_ts()) == n_s - 1
                dropped += 1
                continue
            for method, name in ALGDIFF_METHOD.items():
                d = design(alpha=alpha, beta=beta, N=N, fs=fs, window=n_s / fs, method=method)
                assert d.n_s == n_s
                assert d.omega_c_actual == pytest.approx(o.get_cutoffFreq(), rel=1e-12)
                assert d.delay_s == pytest.approx(o.get_delay(), rel=1e-12, abs=1e-15)
                if N:
                    assert d.theta == pytest.approx(o.get_theta(), abs=1e-14)
                for n in range(3):
                    if n >= min(alpha, beta) + 1 or (method == "trapezoidal" and min(alpha, beta) < n):
                        continue
                    ours = d.weights(n)
                    theirs = o.discretize(n, name)[n][name]
                    assert ours.shape == theirs.shape
                    if not np.all(np.isfinite(theirs)):  # AlgDiff: betainc(t/T > 1 by rounding) = NaN
                        assert method == "analytic" and n == 0 and np.all(np.isfinite(ours))
                        continue
                    # Trapezoidal and analytic rules evaluate g^(n) resp. g^(n-1) at the window end,
                    # AlgDiff at L·t_s, which can land 1 ulp inside T; where that function goes like
                    # (T-τ)^e with 0 < e < 1 (infinite slope) this moves its last coefficient by
                    # ~ulp^e and, through Φ_n, all others. There we compare with AlgDiff's kernel
                    # evaluated at the exact nodes τ = j·T/n_s instead.
                    k = {"midpoint": None, "trapezoidal": n, "analytic": n - 1}[method]
                    if k is not None and any(0 < e - k < 1 for e in (alpha, beta)):
                        theirs = exact_node_weights(o, method, n, n_s, fs, beta)
                    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-10 * np.abs(ours).max())
                    assert d.discrete_delay_s(n) == pytest.approx(o.get_delayDiscrete()[name], rel=1e-12, abs=1e-15)
                    compared += 1
    assert compared > 350 and dropped < len(SWEEP) // 4, (compared, dropped)  # 368 and 4 of 50


@pytest.mark.parametrize(
    "alpha, beta, N, theta, fs, n_s",
    [
        (2, 2, 1, 0.3, 1000.0, 40),
        (1.5, 4, 1, -0.2, 4000.0, 64),
        (3, 2, 2, 0.6, 200.0, 17),
        (6, 6, 2, 1.0, 32000.0, 131),
        (12.5, 9, 1, 0.0, 20.0, 64),
    ],
)
def test_non_default_theta_matches_algdiff(alpha, beta, N, theta, fs, n_s):
    """A chosen ϑ (set_theta; ϑ = 1 is the delay-free one): cutoff of the window (general-N rule),
    delay and mid-point weights of orders 0-2, and the window AlgDiff derives from a cutoff."""
    o = oracle(alpha, beta, N, fs, n_s)
    o.set_theta(theta, False)
    assert int(o.get_T() / o.get_ts()) == n_s  # these windows keep every tap in AlgDiff
    d = design(alpha=alpha, beta=beta, N=N, theta=theta, window=n_s / fs, fs=fs)
    assert d.omega_c_actual == pytest.approx(o.get_cutoffFreq(), rel=1e-12)
    assert d.delay_s == pytest.approx(o.get_delay(), rel=1e-12, abs=1e-15)
    for n in range(3):
        ours = d.weights(n)
        np.testing.assert_allclose(
            ours, o.discretize(n, "mid-point")[n]["mid-point"], rtol=0, atol=1e-10 * np.abs(ours).max()
        )
    omega_c = 0.93 * d.omega_c_actual
    from_cutoff = AlgebraicDifferentiator(ts=1 / fs, alpha=alpha, beta=beta, N=N, T=None, wc=omega_c, display=False)
    from_cutoff.set_theta(theta, False)  # recomputes T from ω_c with this ϑ
    assert design(alpha=alpha, beta=beta, N=N, theta=theta, omega_c=omega_c, fs=fs).n_s == round(
        from_cutoff.get_T() * fs
    )


@pytest.mark.parametrize(
    "alpha, beta, N, omega_c, fs", [(2, 2, 0, 250, 4000), (4.5, 3, 1, 840, 32000), (7, 7, 2, 60, 1000)]
)
def test_window_from_cutoff_matches_algdiff(alpha, beta, N, omega_c, fs):
    d = design(alpha=alpha, beta=beta, N=N, omega_c=omega_c, fs=fs)
    o = AlgebraicDifferentiator(ts=1 / fs, alpha=alpha, beta=beta, N=N, T=None, wc=omega_c, display=False)
    assert d.n_s == round(o.get_T() * fs)


def test_algdiff_drops_a_tap_where_we_keep_n_s():
    """T = 29/200 s: 0.145/0.005 = 28.999999999999996, AlgDiff's int() gives 28 taps."""
    o = oracle(2, 2, 0, 200.0, 29)
    assert o.discretize(1, "mid-point")[1]["mid-point"].size == 28
    assert design(alpha=2, beta=2, window=29 / 200, fs=200).weights(1).size == 29


@pytest.mark.parametrize("n_s", [33, 34])
def test_algdiff_same_convolution_adds_a_sample_for_even_lengths(n_s):
    """Our offline estimate is the causal FIR; AlgDiff's 'same' output lags it by one sample when L is even."""
    fs = 1000.0
    d = design(alpha=3, beta=3, window=n_s / fs, fs=fs)
    o = oracle(3, 3, 0, fs, n_s)
    x = np.sin(np.arange(400) / fs * 7.0) + np.arange(400) / fs
    ours = estimate(d, x, 1)
    theirs = o.estimateDer(1, x, method="mid-point")
    k = np.arange(n_s + 2, 400)
    shift = 1 if n_s % 2 == 0 else 0
    np.testing.assert_allclose(theirs[k], ours[k - shift], rtol=1e-10, atol=1e-10)


def test_algdiff_overflows_for_large_alpha_we_do_not():
    with pytest.raises((OverflowError, ValueError)):
        AlgebraicDifferentiator(ts=1e-3, alpha=100, beta=100, N=0, T=None, wc=100, display=False)
    d = design(alpha=100, beta=100, omega_c=100, fs=1000)
    assert all(np.all(np.isfinite(d.weights(n))) for n in range(3))


def test_trapezoidal_singular_endpoints_refused_where_algdiff_zeroes_them():
    o = oracle(1.5, 3, 0, 1000.0, 20)
    with np.errstate(divide="ignore"):
        assert o.discretize(2, "trapezoidal")[2]["trapezoidal"][0] == 0.0  # g'' ~ τ^(-1/2) there
    with pytest.raises(InvalidParameter, match="method"):
        design(alpha=1.5, beta=3, window=0.02, fs=1000, method="trapezoidal").weights(2)


@pytest.mark.parametrize("alpha, beta, N", [(2, 2, 0), (3, 5.5, 1), (7, 4, 2)])
def test_continuous_and_discrete_spectra_match_algdiff(alpha, beta, N):
    fs = 32000.0
    d = design(alpha=alpha, beta=beta, N=N, omega_c=840, fs=fs)
    o = oracle(alpha, beta, N, fs, d.n_s)
    omega = np.linspace(0, math.pi * fs, 41)
    amp, phase = o.get_ampAndPhaseFilter(omega)
    np.testing.assert_allclose(continuous_response(d, 0, omega), amp * np.exp(1j * phase), rtol=0, atol=1e-12)
    if int(o.get_T() / o.get_ts()) == d.n_s:
        for n in range(3):
            amp_d, phase_d = o.get_ampSpectrumDiscreteFilter(omega, n, "mid-point")
            ours = discrete_response(d, n, omega)
            np.testing.assert_allclose(ours, amp_d * np.exp(1j * phase_d), rtol=0, atol=1e-10 * np.abs(ours).max())


def test_cost_matches_algdiff():
    """J_2 of α = β = 3, ω_c = 840 rad/s, 32 kHz (paper 2, Table 1 setting), 200 frequencies."""
    d = design(alpha=3, beta=3, omega_c=840, fs=32000)
    o = AlgebraicDifferentiator(ts=1 / 32000, alpha=3, beta=3, N=0, T=None, wc=840, display=False)
    assert int(o.get_T() / o.get_ts()) == d.n_s == 205  # here AlgDiff keeps every tap
    j = o.get_discretizationError(2, math.pi * 32000, n=200, method="mid-point")
    assert cost_db(d, 2, points=200) == pytest.approx(20 * math.log10(j), abs=0.01)
