"""The plate filters' designs (labrunner.control.plate_filters) against scipy.signal, the
reference they replace: Butterworth prototypes, the controllable canonical form and Tustin's
bilinear transform, by their matrices and by their frequency responses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from labrunner.control import plate_filters as pf

FS = 32000.0


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_butterworth_equals_scipy(order):
    b, a = pf.lowpass_tf(order, 1200.0)
    rb, ra = signal.butter(order, 1200.0, analog=True)
    np.testing.assert_allclose(b, rb, rtol=1e-14)
    np.testing.assert_allclose(a, ra, rtol=1e-13)


def test_butterworth_has_the_defining_magnitude():
    """|H(iω)|² = 1 / (1 + (ω/ω_c)^{2n}), independent of scipy."""
    b, a = pf.lowpass_tf(4, 500.0)
    w = np.array([10.0, 250.0, 500.0, 2000.0])
    h = np.polyval(b, 1j * w) / np.polyval(a, 1j * w)
    np.testing.assert_allclose(np.abs(h) ** 2, 1.0 / (1.0 + (w / 500.0) ** 8), rtol=1e-12)


@pytest.mark.parametrize(
    "tf",
    [
        pf.notch_tf(942.0, 2.0),
        pf.lowpass_tf(3, 800.0),
        (np.array([2.0, 5.0]), np.array([3.0, 1.0, 7.0])),  # strictly proper, den not monic
        (np.array([1.0, 0.5, 0.25]), np.array([2.0, 3.0, 4.0])),  # proper: a direct feed-through
    ],
)
def test_state_space_and_tustin_equal_scipy(tf):
    ss = pf.tf_ss(*tf)
    ref = signal.tf2ss(*tf)
    for got, want in zip(ss, ref):
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-15)
    warp = 942.0
    dt = 2.0 * np.tan(warp / (2.0 * FS)) / warp
    disc = pf.tustin(ss, FS, warp)
    ref_disc = signal.cont2discrete(ref, dt, method="bilinear")[:4]
    for got, want in zip(disc, ref_disc):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)


def test_tustin_matches_the_continuous_response_at_the_warping_frequency():
    """Prewarping makes the discrete response equal the continuous one exactly at ω_warp."""
    ss = pf.tf_ss(*pf.lowpass_tf(2, 3000.0))
    for warp in (500.0, 3000.0, 9000.0):
        cont = pf.frequency_response(ss, np.array([warp]))
        disc = pf.frequency_response(pf.tustin(ss, FS, warp), np.array([warp]), FS)
        np.testing.assert_allclose(disc, cont, rtol=1e-10)
