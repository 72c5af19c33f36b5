"""Plate geometry and force model against paper 2 eqs. (1)-(4), (11), (12), (15), (18) and rigid-body mechanics."""

import numpy as np
import pytest

from labrunner.errors import InvalidParameter
from labrunner.plate_geometry import (
    PlateGeometry,
    complete_over_actuated,
    current_for_force,
    magnet_force,
    over_actuation_weights,
)

GEO = PlateGeometry()
RNG = np.random.default_rng(7)


def test_table2_constants():
    assert GEO.k1 == pytest.approx(5.13e-2 / (0.144 * 0.117))
    assert GEO.k2 == pytest.approx(8.19e-2 / (0.135 * 0.1825))
    # paper 2 Sec. 4.1: rho = 1/k1 + 1/k2 + 1/m = 0.84 1/kg suggests gamma_F = 0.84; it is -diag(P^-1 B) (eq. (15))
    rho = 1 / GEO.k1 + 1 / GEO.k2 + 1 / GEO.m
    assert rho == pytest.approx(0.84, abs=5e-3)
    np.testing.assert_allclose(np.diag(GEO.P_inv_B[:, :3]), -rho, rtol=1e-12)


def test_eq4_equals_plane_through_three_sensors():
    """h = K y (eq. (4)) is the gap of the plane through sensors 1..3 (eq. (3)) at the magnet points."""
    for _ in range(5):
        y = 2e-3 + 1e-3 * RNG.random(3)
        pts = np.column_stack([GEO.sensor_xy[:3], np.ones(3)])
        c = np.linalg.solve(pts, y)  # gap = c0 x + c1 y + c2
        expected = GEO.magnet_xy @ c[:2] + c[2]
        np.testing.assert_allclose(GEO.gaps_from_sensors(y), expected, rtol=1e-12)


def test_pose_round_trip_and_redundant_sensor():
    pose = np.column_stack(
        [2e-3 + 3e-3 * RNG.random(20), 4e-3 * RNG.standard_normal(20), 4e-3 * RNG.standard_normal(20)]
    )
    y = GEO.sensors_from_pose(pose)
    np.testing.assert_allclose(GEO.pose_from_sensors(y), pose, rtol=1e-10, atol=1e-15)
    # a rigid plate: opposite corners of the sensor rectangle sum alike (Remark 2's redundancy)
    np.testing.assert_allclose(y[:, 0] + y[:, 3], y[:, 1] + y[:, 2], rtol=1e-12)
    np.testing.assert_allclose(GEO.gaps_from_sensors(y), pose @ GEO.magnet_matrix.T, rtol=1e-12)


def test_eq1_matches_newton_euler():
    """ÿ = P⁻¹(B f − m g) (eq. (1), (5)) equals the sensor accelerations of a rigid plate under f."""
    for _ in range(5):
        f = 20 * RNG.random(4)
        x, y = GEO.magnet_xy.T
        pose_acc = np.array([GEO.g - f.sum() / GEO.m, (y * f).sum() / GEO.J_x, -(x * f).sum() / GEO.J_y])
        sensor_acc = GEO.sensor_matrix[:3] @ pose_acc
        np.testing.assert_allclose(GEO.input_from_forces(f) + GEO.g, sensor_acc, rtol=1e-12)


def test_eq11_pseudo_inverse_matches_printed_matrix_and_realises_v():
    m, k1, k2 = GEO.m, GEO.k1, GEO.k2
    printed = 0.25 * np.array(
        [
            [(-k1 - k2) / 2, (-m + k1) / 2, (-m + k2) / 2],
            [(k1 - k2) / 2, (-m - k1) / 2, (-m + k2) / 2],
            [(-k1 + k2) / 2, (-m + k1) / 2, (-m - k2) / 2],
            [(k1 + k2) / 2, (-m - k1) / 2, (-m - k2) / 2],
        ]
    )
    np.testing.assert_allclose(GEO.V, printed, rtol=1e-12)
    v = RNG.standard_normal((10, 3))
    np.testing.assert_allclose(GEO.input_from_forces(GEO.forces_pinv(v)), v, rtol=1e-10, atol=1e-12)
    # Remark 3: the pseudo-inverse has no component along the twist (1, -1, -1, 1) that B cannot see
    np.testing.assert_allclose(GEO.forces_pinv(v) @ np.array([1, -1, -1, 1]), 0.0, atol=1e-12)


def test_eq18_fourth_input():
    x = np.array([[1.0, 2.0, 4.0]])
    np.testing.assert_allclose(
        complete_over_actuated(x, over_actuation_weights()), [[1.0, 2.0, 4.0, 3.0]]
    )  # (F2 + F3)/2
    np.testing.assert_allclose(complete_over_actuated(x, over_actuation_weights((1.0, 0.0, 0.0)))[:, 3], 1.0)
    for bad in [(0.5, 0.5, 0.5), (-0.5, 1.0, 0.5), (1.0, 0.0), "abc", (np.nan, 0.5, 0.5)]:
        with pytest.raises(InvalidParameter, match="weights"):
            over_actuation_weights(bad)


def test_magnet_force_and_eq12_inverse():
    # one quarter of the weight at 2 mm: i = λ^(-1/2) h sqrt(F) = 250 * 2e-3 * sqrt(11.5) A
    f = GEO.m * GEO.g / 4
    i = current_for_force(f, 2e-3)
    assert i == pytest.approx(250 * 2e-3 * np.sqrt(f))
    assert magnet_force(i, 2e-3) == pytest.approx(f)
    assert current_for_force(-3.0, 2e-3) == 0.0  # a pulling magnet cannot push
    # Sec. 4.1 "region A": 4.2 A at the rest gap 5.5 mm cannot lift the plate
    assert 4 * magnet_force(4.2, 5.5e-3) < GEO.m * GEO.g


def test_invalid_geometry():
    with pytest.raises(InvalidParameter, match="m"):
        PlateGeometry(m=-1.0)
