"""StreamingFIR, pad_taps and the offline estimate: equal to np.convolve, batch equal to per-run."""

from __future__ import annotations

import numpy as np
import pytest

from labrunner.differentiators import StreamingFIR, design, estimate, pad_taps
from labrunner.errors import InvalidParameter

RNG = np.random.default_rng(7)


def causal_reference(taps: np.ndarray, x: np.ndarray, fill: float) -> np.ndarray:
    """y[k] = Σ_j taps[j]·x[k−j], history before k = 0 equal to ``fill``, by np.convolve."""
    padded = np.concatenate([np.full(taps.size - 1, fill), x])
    return np.convolve(padded, taps, mode="valid")


def run_stream(fir: StreamingFIR, x: np.ndarray) -> np.ndarray:
    """Feed x (B, K) tick by tick; outputs stacked with time last."""
    return np.stack([fir.step(x[:, k]) for k in range(x.shape[1])], axis=-1)


@pytest.mark.parametrize("length", [1, 2, 14, 61])
def test_single_filter_equals_np_convolve(length):
    taps = RNG.normal(size=length)
    x = RNG.normal(size=(1, 3 * length + 5))
    fir = StreamingFIR(taps)
    fir.reset(1, fill=0.25)
    np.testing.assert_allclose(run_stream(fir, x)[0], causal_reference(taps, x[0], 0.25), rtol=1e-12, atol=1e-12)


def test_shared_taps_over_a_batch_equals_per_run():
    d = design(alpha=3, beta=3, omega_c=200, fs=1000)
    taps = d.weights(1)
    x = RNG.normal(size=(5, 80))
    fill = x[:, 0]
    fir = StreamingFIR(taps)
    fir.reset(5, fill=fill)
    out = run_stream(fir, x)
    assert out.shape == (5, 80)
    for b in range(5):
        np.testing.assert_allclose(out[b], causal_reference(taps, x[b], fill[b]), rtol=1e-12, atol=1e-10)
    tiled = StreamingFIR(np.tile(taps, (5, 1)))  # (B, L) with equal rows: the same numbers
    tiled.reset(5, fill=fill)
    np.testing.assert_allclose(run_stream(tiled, x), out, rtol=1e-12, atol=1e-10)


def test_per_run_taps_of_different_lengths_via_pad_taps():
    designs = [design(alpha=a, beta=a, omega_c=w, fs=1000) for a, w in [(2, 150), (4, 300), (6, 90)]]
    rows = [d.weights(1) for d in designs]
    taps = pad_taps(rows)
    assert taps.shape == (3, max(r.size for r in rows))
    np.testing.assert_array_equal(taps[0, rows[0].size :], 0.0)  # padded at the oldest end
    x = RNG.normal(size=(3, 120))
    fir = StreamingFIR(taps)
    fir.reset(3, fill=x[:, 0])
    out = run_stream(fir, x)
    for b in range(3):
        np.testing.assert_allclose(out[b], causal_reference(rows[b], x[b], x[b, 0]), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("shared", [True, False])
def test_filter_bank_per_run_gives_b_by_m(shared):
    d = design(alpha=4, beta=4, omega_c=150, fs=1000)
    bank = pad_taps([d.weights(n) for n in range(3)])  # (M, L): derivatives 0, 1, 2
    scale = np.ones(4) if shared else np.array([1.0, 2.0, -1.0, 0.5])
    taps = scale[:, None, None] * bank[None]  # (B, M, L)
    x = RNG.normal(size=(4, 60))
    fir = StreamingFIR(taps)
    fir.reset(4, fill=x[:, 0])
    out = np.stack([fir.step(x[:, k]) for k in range(60)], axis=-1)  # (B, M, K)
    assert out.shape == (4, 3, 60)
    for b in range(4):
        for m in range(3):
            ref = scale[b] * causal_reference(bank[m], x[b], x[b, 0])
            np.testing.assert_allclose(out[b, m], ref, rtol=1e-11, atol=1e-7)


def test_reset_fill_gives_a_steady_start():
    """A constant history: the derivative estimate of a constant signal is 0 from the first tick."""
    d = design(alpha=2, beta=2, omega_c=100, fs=1000)
    fir = StreamingFIR(d.weights(1))
    fir.reset(2, fill=np.array([3.0, -1.0]))
    for _ in range(5):
        np.testing.assert_allclose(fir.step(np.array([3.0, -1.0])), 0.0, atol=1e-9)
    fir0 = StreamingFIR(d.weights(0))
    fir0.reset(1, fill=2.0)
    assert fir0.step(np.array([2.0]))[0] == pytest.approx(2.0, rel=1e-12)


def test_reset_validation():
    fir = StreamingFIR(np.ones((3, 4)))
    with pytest.raises(InvalidParameter, match="batch"):
        fir.reset(2)
    with pytest.raises(InvalidParameter, match="fill"):
        fir.reset(3, fill=np.zeros(2))
    with pytest.raises(InvalidParameter, match="taps"):
        StreamingFIR(np.ones((2, 2, 2, 2)))
    with pytest.raises(InvalidParameter, match="taps"):
        StreamingFIR(np.array([1.0, np.nan]))
    with pytest.raises(InvalidParameter, match="taps"):
        pad_taps([])


@pytest.mark.parametrize("method", ["midpoint", "trapezoidal", "analytic"])
def test_offline_estimate_equals_streaming(method):
    d = design(alpha=3, beta=2, omega_c=120, fs=1000, method=method)
    x = np.cumsum(RNG.normal(size=(2, 300)), axis=1)
    y = estimate(d, x, 1)
    fir = StreamingFIR(d.weights(1))
    fir.reset(2, fill=x[:, 0])
    np.testing.assert_allclose(y, run_stream(fir, x), rtol=1e-9, atol=1e-9 * np.abs(y).max())
    np.testing.assert_allclose(estimate(d, x[0], 1), y[0], rtol=1e-12, atol=1e-12 * np.abs(y).max())


@pytest.mark.parametrize("method", ["midpoint", "trapezoidal"])
def test_offline_estimate_alignment_is_the_discrete_delay(method):
    """α = β (exact for quadratics): estimate(x = t²)[k] = 2(k t_s − discrete_delay_s) once the
    window is full; no sample of extra delay for even or odd window lengths."""
    for window in (0.020, 0.021):
        d = design(alpha=4, beta=4, window=window, fs=1000, method=method)
        t = np.arange(200) / d.fs
        y = estimate(d, t**2, 1)
        k = np.arange(d.weights(1).size, 200)
        np.testing.assert_allclose(y[k], 2 * (t[k] - d.discrete_delay_s(1)), rtol=1e-10, atol=1e-12)
