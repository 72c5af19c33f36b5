"""Plate reference trajectories against paper 2 Sec. 4.1, 4.3 (levels, transition and hold times, poly-5 shape)."""

import numpy as np
import pytest

from labrunner.control.plate_trajectories import lift, reference_from_points, tilt
from labrunner.errors import InvalidParameter
from labrunner.rigs.sim.plate import PlateTwin

INFO = PlateTwin.nominal_info("plate-sim", "", {})


def test_lift_levels_and_times():
    y1, y2, y3 = lift()
    assert y1 == y2 == y3  # the same trajectory for the three sensor points
    # 5.5 → 2 mm in 2 s, settle 0.5 s, 2 → 5 mm in 0.5 s, hold 0.2 s, 5 → 2 mm in 0.5 s, hold 0.2 s
    assert y1.duration == pytest.approx(2.0 + 0.5 + 0.5 + 0.2 + 0.5 + 0.2)
    t = np.array([0.0, 2.0, 2.5, 3.0, 3.2, 3.7, 3.9])
    np.testing.assert_allclose(y1.evaluate(t)[:, 0], [5.5e-3, 2e-3, 2e-3, 5e-3, 5e-3, 2e-3, 2e-3], atol=1e-15)
    np.testing.assert_allclose(y1.evaluate(t)[:, 1:3], 0.0, atol=1e-15)  # at rest at every level
    # poly-5: the largest speed, at mid-transition, is 15/8 Δ/T
    assert y1.evaluate(np.array([1.0]))[0, 1] == pytest.approx(-15 / 8 * 3.5e-3 / 2.0)
    assert y1.evaluate(np.array([2.75]))[0, 1] == pytest.approx(15 / 8 * 3e-3 / 0.5)


def test_tilt_transition_times():
    """Fig. 12: from 2 mm, y_2's transition is done after 0.25 s, y_3's after 0.5 s; all return to 2 mm."""
    trs = tilt(lift_s=2.0, settle_s=0.5)
    start = 2.5  # lifted to the hover height and settled
    ends = {0: start + 0.75, 1: start + 0.25, 2: start + 0.5}
    for k, tr in enumerate(trs):
        v = tr.evaluate(np.array([0.0, start, ends[k] - 1e-3, ends[k], start + 0.75 + 0.5 - 1e-9]))[:, 0]
        assert v[0] == pytest.approx(5.5e-3) and v[1] == pytest.approx(2e-3)
        assert v[3] == pytest.approx((2.5e-3, 1.5e-3, 2.5e-3)[k])
        assert v[4] == pytest.approx(v[3])  # still tilted while the slowest finishes and holds
        assert abs(v[2] - v[3]) < 1e-6
        assert tr.evaluate(np.array([tr.duration]))[0, 0] == pytest.approx(2e-3)
    # each returns with its own transition time after the common hold
    np.testing.assert_allclose([tr.duration for tr in trs], [start + 0.75 + 0.5 + t + 0.5 for t in (0.75, 0.25, 0.5)])


def test_reference_from_points_delay_and_defaults():
    points = [
        {"reference": {"kind": "lift", "delay": True}},
        {"reference": {"kind": "lift", "delay": True, "hover": 3e-3}},
    ]
    delays = np.array([0.004, 0.002])
    ref = reference_from_points(points, INFO, delays_s=delays)
    assert ref.batch == 2 and ref.n_outputs == 3
    undelayed = lift()[0]
    t = np.linspace(0.0, 3.0, 7)
    np.testing.assert_allclose(ref.evaluate(t + 0.004)[:, 0, 0, :], undelayed.evaluate(t), atol=1e-15)
    assert ref.evaluate(np.array([2.3]))[0, 1, 2, 0] == pytest.approx(3e-3)


def test_reference_validation():
    with pytest.raises(InvalidParameter, match="reference.delay"):
        reference_from_points([{"reference": {"kind": "lift", "delay": True}}], INFO, delays_s=None)
    with pytest.raises(InvalidParameter, match="reference.hover"):
        reference_from_points([{"reference": {"kind": "lift", "hover": -1e-3}}], INFO, delays_s=None)
    with pytest.raises(InvalidParameter, match="reference.transitions"):
        reference_from_points([{"reference": {"kind": "tilt", "transitions": [0.1, 0.0, 0.2]}}], INFO, delays_s=None)
    with pytest.raises(InvalidParameter, match="reference.speed"):
        reference_from_points([{"reference": {"kind": "lift", "speed": 1.0}}], INFO, delays_s=None)
    # the generic kinds still work, nested per output
    ref = reference_from_points(
        [
            {
                "reference": {
                    "kind": "setpoints",
                    "levels": [[2e-3, 3e-3], [2e-3, 2e-3], [2e-3, 1e-3]],
                    "transition": 0.5,
                    "hold": 0.1,
                }
            }
        ],
        INFO,
        delays_s=None,
    )
    np.testing.assert_allclose(ref.evaluate(np.array([0.7]))[0, 0, :, 0], [3e-3, 2e-3, 1e-3])
