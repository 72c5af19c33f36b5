"""MBC estimation chain of paper 2 Sec. 4.2: observer (10), notch, matched low-pass filters, Tustin with prewarping."""

import numpy as np
import pytest

from labrunner.control.factory import build
from labrunner.control.plate_filters import (
    frequency_response,
    identity,
    lowpass_tf,
    notch_tf,
    parallel,
    series,
    tf_ss,
    tustin,
)
from labrunner.control.plate_mbc import MBCDesign, estimation_chain, matched_orders, observer_gains, observer_ss
from labrunner.differentiators import design
from labrunner.differentiators.spectra import continuous_response
from labrunner.errors import InvalidParameter
from labrunner.rigs.sim.plate import PlateTwin

FS = 32_000.0
DESIGN = MBCDesign()


def test_observer_eigenvalues():
    l = observer_gains((820.0, 840.0, 860.0))
    # (s + 820)(s + 840)(s + 860) = s³ + 2520 s² + 2116400 s + 592368000
    np.testing.assert_allclose(l, [2520.0, 2116400.0, 592368000.0])
    A = observer_ss((820.0, 840.0, 860.0))[0]
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(A).real), [-860.0, -840.0, -820.0], rtol=1e-6)


def test_observer_is_exact_for_the_model():
    """For ÿ = v + g + η with constant η, the observer's estimates are exact in steady state: ŷ = y,
    ŷ̇ = ẏ, η̂ = ÿ − (v + g) (low-frequency limits of the transfer functions of (10))."""
    H = frequency_response(observer_ss(DESIGN.observer_poles), np.array([1e-3]))[0]
    s = 1j * 1e-3
    np.testing.assert_allclose(H[:, 0], [1.0, s, s * s], rtol=1e-3, atol=1e-12)
    np.testing.assert_allclose(H[:, 1], [0.0, 0.0, -1.0], atol=1e-5)


@pytest.mark.parametrize("part", ["notch", "observer", "lowpass"])
def test_tustin_prewarp_exact_at_its_frequency(part):
    cont = {
        "notch": (tf_ss(*notch_tf(942.0, 2.0)), 942.0),
        "observer": (observer_ss(DESIGN.observer_poles), 840.0),
        "lowpass": (parallel([tf_ss(*lowpass_tf(q, 840.0)) for q in (4, 3, 2)]), 840.0),
    }[part]
    ss, warp = cont
    disc = estimation_chain(DESIGN)[part]
    at = np.array([warp])
    np.testing.assert_allclose(frequency_response(disc, at, FS), frequency_response(ss, at), rtol=1e-9, atol=1e-12)
    # plain Tustin (warped at ~0 rad/s) misses the continuous response there: the prewarp does the work
    plain = tustin(ss, FS, 1e-6)
    error = np.abs(frequency_response(plain, at, FS) - frequency_response(ss, at)).max()
    assert error > 1e-6 * np.abs(frequency_response(ss, at)).max()
    # discrete poles are the bilinear images z = (1 + s T/2)/(1 − s T/2), T prewarped
    T = 2 * np.tan(warp / (2 * FS)) / warp
    s = np.linalg.eigvals(ss[0])
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(disc[0])), np.sort_complex((1 + s * T / 2) / (1 - s * T / 2)), rtol=1e-8
    )


def test_notch_depth_and_width():
    notch = estimation_chain(DESIGN)["notch"]
    H = lambda w: abs(frequency_response(notch, np.array([w]), FS)[0, 0, 0])  # noqa: E731
    assert H(942.0) < 1e-9  # the zero sits exactly at 942 rad/s after prewarping
    assert H(0.0) == pytest.approx(1.0, abs=1e-12)
    assert H(100.0) > 0.99 and H(10_000.0) > 0.99
    half = 942.0 / 2.0 / 2  # −3 dB band of width ω0/Q around ω0 (approximately symmetric in log)
    assert H(942.0 - half * 0.99) < H(942.0 - half * 1.3)


def test_chain_estimates_at_low_frequency():
    H = frequency_response(estimation_chain(DESIGN)["chain"], np.array([1.0]), FS)[0]
    s = 1j
    np.testing.assert_allclose(H[:, 0], [1.0, s, s * s], rtol=1e-2)  # up to the filters' small lag
    assert H[2, 1].real == pytest.approx(-1.0, rel=1e-2)  # η̂ = ÿ − (v + g)


def test_lowpass_orders_match_differentiator_slopes():
    """With the low-pass filters the chain's stop-band slopes equal the differentiator's 20(μ − n) dB/decade,
    μ = 1 + min(α, β) = 5 for α = β = 4 (Othmane et al. 2022 Sec. 4.2.2, paper 2 Fig. 9)."""
    assert matched_orders(4, 4) == (4, 3, 2)
    assert matched_orders(2, 3) == (2, 1, 0)
    cont = series(
        series(parallel([tf_ss(*notch_tf(942.0, 2.0)), identity()]), observer_ss(DESIGN.observer_poles)),
        parallel([tf_ss(*lowpass_tf(q, 840.0)) for q in matched_orders(4, 4)]),
    )
    H = np.abs(frequency_response(cont, np.array([1e5, 1e6]))[:, :, 0])
    slopes = 20 * np.log10(H[1] / H[0])
    np.testing.assert_allclose(slopes, [-20 * (5 - n) for n in range(3)], atol=0.1)
    # without them the observer alone falls with only 20 dB/decade on every estimate
    H0 = np.abs(frequency_response(observer_ss(DESIGN.observer_poles), np.array([1e5, 1e6]))[:, :, 0])
    np.testing.assert_allclose(20 * np.log10(H0[1] / H0[0]), [-20, -20, -20], atol=0.5)


def test_chain_amplitude_matches_the_differentiator_up_to_its_cutoff():
    """Paper 2 Sec. 4.2, Fig. 9: observer + notch + low-pass (discretised, 32 kHz) and the algebraic
    differentiator (α = β = 4, ω_c = 840 rad/s, continuous spectrum) combined with the notch have
    similar amplitude spectra up to the cutoff: within 4 dB of each other for ω ≤ ω_c/2 relative to
    the ideal |jω|ⁿ, and both at least 6 dB down at ω_c (the observer's cutoff is also ≈ 840 rad/s)."""
    w = np.array([10.0, 50.0, 100.0, 200.0, 300.0, 420.0])
    chain = frequency_response(estimation_chain(DESIGN)["chain"], np.r_[w, 840.0], FS)[:, :, 0]
    notch = frequency_response(tf_ss(*notch_tf(942.0, 2.0)), np.r_[w, 840.0])[:, 0, 0]
    d = design(alpha=4, beta=4, fs=FS, omega_c=840.0)
    for n in range(3):
        ideal = np.r_[w, 840.0] ** n
        mbc = 20 * np.log10(np.abs(chain[:, n]) / ideal)
        mfc = 20 * np.log10(np.abs(continuous_response(d, n, np.r_[w, 840.0]) * notch) / ideal)
        np.testing.assert_allclose(mbc[:-1], mfc[:-1], atol=4.0, err_msg=f"derivative {n}")
        assert mbc[0] == pytest.approx(0.0, abs=0.05) and mfc[0] == pytest.approx(0.0, abs=0.05)
        assert mbc[-1] < -6.0 and mfc[-1] < -6.0


def test_discrete_chain_is_stable_and_causal():
    A = estimation_chain(DESIGN)["chain"][0]
    assert np.abs(np.linalg.eigvals(A)).max() < 1.0


def test_design_validation():
    with pytest.raises(InvalidParameter, match="notch_omega"):
        MBCDesign(notch_omega=2e5)
    with pytest.raises(InvalidParameter, match="c_p"):
        MBCDesign(c_p=-1.0)


def test_builder_validation():
    info = PlateTwin.nominal_info("plate-sim", "", {})
    base = {"controller": {"kind": "plate-mbc"}, "reference": {"kind": "lift"}}
    controller, ref = build([base], info, FS)
    assert controller.output_names == ("y1", "y2", "y3") and ref.n_outputs == 3
    with pytest.raises(InvalidParameter, match="controller.observer_poles"):
        build([{**base, "controller": {"kind": "plate-mbc", "observer_poles": [800, 900]}}], info, FS)
    with pytest.raises(InvalidParameter, match="controller.notch_omega"):
        build([{**base, "controller": {"kind": "plate-mbc", "notch_omega": 1e6}}], info, FS)
    with pytest.raises(InvalidParameter, match="differentiator"):
        build([{**base, "differentiator": {"alpha": 4, "omega_c": 840}}], info, FS)
    with pytest.raises(InvalidParameter, match="controller.k_p"):
        build([{**base, "controller": {"kind": "plate-mbc", "k_p": 5000}}], info, FS)
    with pytest.raises(InvalidParameter, match="reference.delay"):
        build([{**base, "reference": {"kind": "lift", "delay": True}}], info, FS)
