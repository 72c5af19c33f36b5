"""Reference trajectories: poly-5 set points against an independently solved quintic, steps, sines,
delays, the batched Reference, and the shapes the thesis and papers use."""

import numpy as np
import pytest

from labrunner.control.trajectories import Reference, Setpoints, Sine, Steps
from labrunner.errors import InvalidParameter


def quintic(a: float, b: float, T: float) -> np.poly1d:
    """The degree-5 polynomial with p(0)=a, p(T)=b and zero first and second derivatives at both
    ends, solved from its six boundary conditions."""
    basis = [np.poly1d(row) for row in np.eye(6)]
    rows = [[np.polyder(p, d)(t) if d else p(t) for p in basis] for t in (0.0, T) for d in range(3)]
    return np.poly1d(np.linalg.solve(np.array(rows), [a, 0.0, 0.0, b, 0.0, 0.0]))


def test_transition_matches_independent_quintic_and_its_derivatives():
    sp = Setpoints.build([2.0, -3.0], transition=0.7, hold=[0.3, 0.5])
    coeffs = quintic(2.0, -3.0, 0.7)
    t = np.linspace(0.3 + 1e-9, 1.0 - 1e-9, 57)
    got = sp.evaluate(t)
    for n in range(4):
        np.testing.assert_allclose(got[:, n], np.polyder(coeffs, n)(t - 0.3), rtol=1e-9, atol=1e-9)


def test_holds_and_duration_of_the_papers_shapes():
    valve = Setpoints.build([1.0, 5.0, 1.0], transition=5.0, hold=5.0)  # paper 1 Sec. 5.1
    assert valve.duration == pytest.approx(25.0)
    np.testing.assert_allclose(valve.evaluate([0.0, 4.9, 10.0, 14.9, 20.0, 25.0, 30.0])[:, 0], [1, 1, 5, 5, 1, 1, 1])
    plate = Setpoints.build([5.5e-3, 2e-3, 5e-3, 2e-3], transition=[2.0, 0.5, 0.5], hold=[0.0, 0.2, 0.2, 0.2])
    assert plate.duration == pytest.approx(3.6)  # paper 2 Sec. 4.1: lift in 2 s, then 2 → 5 → 2 mm
    np.testing.assert_allclose(
        plate.evaluate([0.0, 2.0, 2.2, 2.7, 2.9, 3.4, 3.6])[:, 0], [5.5e-3, 2e-3, 2e-3, 5e-3, 5e-3, 2e-3, 2e-3]
    )
    thesis = Setpoints.build([0.0, 20.0, 0.0], transition=1.0, hold=1.0)  # Ω_r 0 → level → 0 (ch. 3)
    assert thesis.evaluate([2.0])[0, 0] == pytest.approx(20.0) and thesis.duration == pytest.approx(5.0)


def test_derivatives_are_consistent_with_the_values():
    """Integrating derivative n+1 (mid-point rule, mid-times never hit the jumps of the third
    derivative at the transition ends) gives derivative n."""
    sp = Setpoints.build([0.0, 1.0, -0.5], transition=[0.4, 0.6], hold=[0.1, 0.2, 0.3])
    t = np.linspace(0.0, sp.duration, 100001)
    x, mid = sp.evaluate(t), sp.evaluate((t[1:] + t[:-1]) / 2)
    for n in range(3):
        integrated = x[0, n] + np.concatenate([[0.0], np.cumsum(mid[:, n + 1] * np.diff(t))])
        np.testing.assert_allclose(integrated, x[:, n], atol=1e-6 * np.abs(x[:, n]).max())


def test_delay_shifts_the_whole_trajectory():
    sp = Setpoints.build([0.0, 20.0, 0.0], transition=1.0, hold=1.0)
    late = sp.delayed(0.035)
    t = np.linspace(0.0, 6.0, 601)
    np.testing.assert_allclose(late.evaluate(t + 0.035)[:, :3], sp.evaluate(t)[:, :3], rtol=0, atol=1e-9)
    assert late.duration == pytest.approx(5.035)
    assert late.evaluate([0.02])[0, 0] == 0.0


def test_steps_and_sine():
    st = Steps.build([-12.0, -6.0, 6.0, 12.0], durations=1.0)  # thesis Sec. 3.2 identification steps
    np.testing.assert_array_equal(st.evaluate([0.0, 0.99, 1.0, 2.5, 3.5, 9.0])[:, 0], [-12, -12, -6, 6, 12, 12])
    assert np.all(st.evaluate(np.linspace(0, 5, 11))[:, 1:] == 0.0)
    sn = Sine.build(amplitude=6.0, frequency=1.0, duration=3.0)  # thesis Fig. 3.1
    t = np.linspace(0.0, 2.99, 300)
    w = 2 * np.pi
    expected = np.stack(
        [6 * np.sin(w * t), 6 * w * np.cos(w * t), -6 * w**2 * np.sin(w * t), -6 * w**3 * np.cos(w * t)], axis=1
    )
    np.testing.assert_allclose(sn.evaluate(t), expected, atol=1e-9)
    assert np.all(sn.evaluate([3.0, 4.0]) == 0.0)


def test_batched_reference_equals_each_trajectory():
    sp = Setpoints.build([0.0, 20.0, 0.0], transition=1.0, hold=1.0)
    rows = [
        [sp],
        [sp.delayed(0.01)],
        [Setpoints.build([1.0, 2.0, 3.0, 4.0], [0.1, 0.2, 0.3], 0.05)],
        [Steps.build([1.0, 2.0], 0.5)],
        [Sine.build(2.0, 3.0, 1.0)],
    ]
    ref = Reference(rows)
    t = np.linspace(0.0, 6.0, 1201)
    got = ref.evaluate(t)
    assert got.shape == (t.size, 5, 1, 4)
    for b, (tr,) in enumerate(rows):
        np.testing.assert_array_equal(got[:, b, 0, :], tr.evaluate(t))
    assert ref.duration == pytest.approx(5.01)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(levels=[0.0, 1.0], transition=-1.0, hold=1.0), "reference.transition"),
        (dict(levels=[0.0, 1.0], transition=0.0, hold=1.0), "reference.transition"),
        (dict(levels=[0.0, 1.0], transition=[1.0, 2.0], hold=1.0), "reference.transition"),
        (dict(levels=[0.0, 1.0], transition=1.0, hold=[1.0]), "reference.hold"),
        (dict(levels=[], transition=1.0, hold=1.0), "reference.levels"),
        (dict(levels=[0.0, float("nan")], transition=1.0, hold=1.0), "reference.levels"),
    ],
)
def test_bad_setpoints_name_the_key(kwargs, field):
    with pytest.raises(InvalidParameter) as err:
        Setpoints.build(**kwargs)
    assert err.value.field == field
