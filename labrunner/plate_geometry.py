"""Geometry and force model of paper 2's magnetically supported plate, shared by twin and controllers.

Frame: the plate's centre of mass at (x, y) = (0, 0); an *air gap* grows downwards (the plate
hangs below four magnets). A pose is ``(z, φ_x, φ_y)``: the gap at the centre [m] and the small
tilt angles about the body x- and y-axes [rad] (right-handed, z_0 up), so that the gap at a point
(x, y) of the plate is ``z − y·φ_x + x·φ_y``.

Sensors 1..4 sit at (−l_dx, +l_dy), (−l_dx, −l_dy), (+l_dx, +l_dy), (+l_dx, −l_dy) (paper 2 eq. (3)),
magnets 1..4 at the same corners with l_fx, l_fy (read off eq. (4)). Only sensors 1..3 define the
plane (eq. (4)); sensor 4 is redundant (Remark 2).

All functions take a batch axis first and broadcast over leading axes.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np

from labrunner.errors import InvalidParameter, check_finite

#: λ^(−1/2) of the approximation d_j(h) ≈ λ^(−1/2)·h (paper 2 Sec. 3.2.3, Fig. 3) [A s/(kg m³)^(1/2)].
LAMBDA_INV_SQRT = 250.0

_CORNER_SIGNS = np.array([[-1.0, 1.0], [-1.0, -1.0], [1.0, 1.0], [1.0, -1.0]])  # (sign x, sign y) of corner j


@dataclass(frozen=True)
class PlateGeometry:
    """Rigid-plate parameters of paper 2 Table 2 (SI units: kg, kg m², m, m/s²)."""

    m: float = 4.69
    g: float = 9.81
    J_x: float = 5.13e-2
    J_y: float = 8.19e-2
    l_dx: float = 0.135
    l_dy: float = 0.144
    l_fx: float = 0.1825
    l_fy: float = 0.117

    def __post_init__(self) -> None:
        for f in fields(self):
            if not check_finite(f.name, getattr(self, f.name)) > 0.0:
                raise InvalidParameter(f.name, f"must be > 0, got {getattr(self, f.name)!r}")

    # -- constants of eq. (1) and (4) ------------------------------------------------------------
    @property
    def k1(self) -> float:
        """k_1 = J_x / (l_dy l_fy) [kg] (paper 2 eq. (1))."""
        return self.J_x / (self.l_dy * self.l_fy)

    @property
    def k2(self) -> float:
        """k_2 = J_y / (l_dx l_fx) [kg] (paper 2 eq. (1))."""
        return self.J_y / (self.l_dx * self.l_fx)

    @property
    def kx(self) -> float:
        """k_x = l_fx / l_dx (paper 2 eq. (4), read as in SEED-NOTES)."""
        return self.l_fx / self.l_dx

    @property
    def ky(self) -> float:
        """k_y = l_fy / l_dy (paper 2 eq. (4))."""
        return self.l_fy / self.l_dy

    @cached_property
    def sensor_xy(self) -> np.ndarray:
        """(4, 2) sensor positions [m]."""
        return _CORNER_SIGNS * np.array([self.l_dx, self.l_dy])

    @cached_property
    def magnet_xy(self) -> np.ndarray:
        """(4, 2) force points (yoke centres) [m]."""
        return _CORNER_SIGNS * np.array([self.l_fx, self.l_fy])

    @cached_property
    def B(self) -> np.ndarray:
        """(3, 4) force-combination matrix of eq. (1)."""
        return np.array([[1.0, 1.0, 1.0, 1.0], [1.0, -1.0, 1.0, -1.0], [1.0, 1.0, -1.0, -1.0]])

    @cached_property
    def P(self) -> np.ndarray:
        """(3, 3) inertia matrix of eq. (1): B f = m g + P(ÿ − η)."""
        m, k1, k2 = self.m, self.k1, self.k2
        return np.array([[0.0, -m / 2, -m / 2], [-k1 / 2, k1 / 2, 0.0], [-k2 / 2, 0.0, k2 / 2]])

    @cached_property
    def P_inv_B(self) -> np.ndarray:
        """(3, 4) map from magnet forces f to the input v = P⁻¹ B f [m/s²] (eq. (5))."""
        return np.linalg.solve(self.P, self.B)

    @cached_property
    def K(self) -> np.ndarray:
        """(4, 3) map from sensors (y_1, y_2, y_3) to the magnet air gaps h (eq. (4))."""
        kx, ky = self.kx, self.ky
        return 0.5 * np.array(
            [
                [kx + ky, 1 - ky, 1 - kx],
                [kx - ky, 1 + ky, 1 - kx],
                [-kx + ky, 1 - ky, 1 + kx],
                [-kx - ky, 1 + ky, 1 + kx],
            ]
        )

    @cached_property
    def V(self) -> np.ndarray:
        """(4, 3) allocation f_d = B† P v with the Moore–Penrose pseudo-inverse (eq. (11))."""
        return np.linalg.pinv(self.B) @ self.P

    # -- poses and gaps ------------------------------------------------------------------------
    def point_matrix(self, xy: np.ndarray) -> np.ndarray:
        """(n, 3) map from a pose (z, φ_x, φ_y) to the gaps at the n points ``xy`` (n, 2)."""
        xy = np.asarray(xy, dtype=float)
        return np.column_stack([np.ones(len(xy)), -xy[:, 1], xy[:, 0]])

    @cached_property
    def sensor_matrix(self) -> np.ndarray:
        """(4, 3) pose → the four sensor readings."""
        return self.point_matrix(self.sensor_xy)

    @cached_property
    def magnet_matrix(self) -> np.ndarray:
        """(4, 3) pose → the four magnet air gaps."""
        return self.point_matrix(self.magnet_xy)

    @cached_property
    def pose_from_sensor_matrix(self) -> np.ndarray:
        """(3, 3) sensors (y_1, y_2, y_3) → pose: the plane through three points (eq. (3))."""
        return np.linalg.inv(self.sensor_matrix[:3])

    def pose_from_sensors(self, y: np.ndarray) -> np.ndarray:
        """(…, 3) pose (z, φ_x, φ_y) from the first three sensor readings ``y`` (…, ≥3) [m]."""
        return np.asarray(y)[..., :3] @ self.pose_from_sensor_matrix.T

    def sensors_from_pose(self, pose: np.ndarray) -> np.ndarray:
        """(…, 4) sensor readings of a rigid plate in ``pose`` (…, 3)."""
        return np.asarray(pose) @ self.sensor_matrix.T

    def gaps_from_sensors(self, y: np.ndarray) -> np.ndarray:
        """(…, 4) magnet air gaps h = K y from sensors 1..3 (paper 2 eq. (4))."""
        return np.asarray(y)[..., :3] @ self.K.T

    # -- forces ---------------------------------------------------------------------------------
    def input_from_forces(self, f: np.ndarray) -> np.ndarray:
        """(…, 3) v = P⁻¹ B f [m/s²]: ÿ = v + g·(1, 1, 1) + η (paper 2 eq. (5))."""
        return np.asarray(f) @ self.P_inv_B.T

    def forces_pinv(self, v: np.ndarray) -> np.ndarray:
        """(…, 4) desired forces f_d = V v [N] (paper 2 eq. (11))."""
        return np.asarray(v) @ self.V.T


def over_actuation_weights(weights: object = (0.0, 0.5, 0.5)) -> np.ndarray:
    """Validated a_k of paper 2 eq. (18): three numbers ≥ 0 with Σ a_k = 1 (Sec. 4.1: (0, ½, ½))."""
    try:
        a = np.asarray(weights, dtype=float)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0) or not np.isclose(a.sum(), 1.0):
        raise InvalidParameter("weights", f"need three a_k >= 0 with sum 1 (paper 2 eq. (18)), got {weights!r}")
    return a


def complete_over_actuated(x3: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(…, 4): (x_1, x_2, x_3, Σ a_k x_k), the fourth actuator's input by paper 2 eq. (18).

    ``x3`` are the forces, u = (i/h)² or currents of the three sensor-point MFCs; ``weights`` the
    a_k from :func:`over_actuation_weights`. F_d,4 = (F_2 + F_3)/2 for a = (0, ½, ½).
    """
    x3 = np.asarray(x3, dtype=float)
    return np.concatenate([x3, x3 @ weights[:, None]], axis=-1)


def magnet_force(i: np.ndarray, h: np.ndarray, lam_inv_sqrt: float | np.ndarray = LAMBDA_INV_SQRT) -> np.ndarray:
    """F = i²/d(h)² with d(h) = λ^(−1/2)·h [N] (paper 2 eq. (2), Sec. 3.2.3); ``i`` [A], ``h`` [m]."""
    return force_at(np.asarray(i), lam_inv_sqrt * np.asarray(h))


def current_for_force(f: np.ndarray, h: np.ndarray, lam_inv_sqrt: float | np.ndarray = LAMBDA_INV_SQRT) -> np.ndarray:
    """i_d = d(h)·√F_d [A], the inverse of :func:`magnet_force` (paper 2 eq. (12)); F_d < 0 → 0 A."""
    return current_at(f, lam_inv_sqrt * np.asarray(h))


def force_at(i: np.ndarray, d: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """F = (i/d)² [N] for a given d(h) [A s/(kg m)^(1/2)·m] (eq. (2)); into ``out`` if given (a tick's buffer)."""
    if out is None:
        return np.square(np.divide(i, d))
    return np.square(np.divide(i, d, out=out), out=out)


def current_at(f: np.ndarray, d: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """i = d·√F for F ≥ 0, 0 A for F < 0 (eq. (12)) at a given d(h); into ``out`` (may be ``f``) if given."""
    if out is None:
        return np.multiply(d, np.sqrt(np.maximum(f, 0.0)))
    return np.multiply(d, np.sqrt(np.maximum(f, 0.0, out=out), out=out), out=out)
