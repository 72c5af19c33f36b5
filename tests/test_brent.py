"""labrunner.brent.brent_root against scipy.optimize.brentq (the reference it replaces) and
against roots known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from labrunner.brent import brent_root
from labrunner.errors import InvalidParameter
from labrunner.stability.roots import dsinc, sinc

FUNCTIONS = {
    "cos": np.cos,
    "cubic": lambda x: x**3 - 2.0 * x - 5.0,
    "exp": lambda x: math.exp(x) - 10.0,
    "first-order crossing aδ=0.7": lambda z: math.cos(z) + 0.7 * float(sinc(z)),
    "d'(z) of A.6": lambda z: math.sin(z) + z * math.cos(z) - 2.0 * float(dsinc(z)) + 0.5 * math.sin(z),
    "steep": lambda x: math.atan(1e4 * (x - 0.3)),
}


@pytest.mark.parametrize("name", FUNCTIONS)
@pytest.mark.parametrize(("xtol", "rtol"), [(1e-15, 1e-15), (2e-12, 8.9e-16), (1e-6, 1e-10)])
def test_agrees_with_scipy_brentq_within_the_tolerance(name, xtol, rtol):
    f = FUNCTIONS[name]
    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(300):
        a, b = sorted(rng.uniform(-3.0, 6.0, 2))
        if f(a) * f(b) >= 0.0:
            continue
        ref = brentq(f, a, b, xtol=xtol, rtol=rtol)
        got = brent_root(f, a, b, xtol=xtol, rtol=rtol)
        assert abs(got - ref) <= xtol + rtol * abs(ref), (a, b)
        assert a <= got <= b
        checked += 1
    assert checked > 20


def test_closed_form_roots_to_the_last_digits():
    assert brent_root(np.cos, 0.0, 3.0, xtol=1e-15, rtol=1e-15) == pytest.approx(math.pi / 2, abs=2e-15)
    assert brent_root(lambda x: x * x - 2.0, 0.0, 2.0, xtol=1e-15, rtol=1e-15) == pytest.approx(math.sqrt(2), abs=3e-15)
    # tan z = −z/(aδ) at aδ = 1 (the first-order bound of thesis (2.46)) by Newton from high precision
    z = brent_root(lambda z: math.cos(z) + math.sin(z) / z, 1.6, 3.1, xtol=1e-15, rtol=1e-15)
    assert z == pytest.approx(2.028757838110434, abs=1e-14)


def test_an_end_that_is_a_root_is_returned_and_a_bracket_without_a_sign_change_is_refused():
    assert brent_root(lambda x: x - 1.0, 1.0, 2.0) == 1.0
    assert brent_root(lambda x: x - 2.0, 1.0, 2.0) == 2.0
    with pytest.raises(InvalidParameter, match=r"^bracket: f must change sign on \[0.0, 1.0\]"):
        brent_root(lambda x: x + 1.0, 0.0, 1.0)
