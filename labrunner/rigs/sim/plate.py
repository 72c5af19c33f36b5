"""Simulated twin of paper 2's magnetically supported plate (batch-vectorised, 32 kHz by default).

Rigid body in three degrees of freedom (centre gap z, tilts φ_x, φ_y; see
:mod:`labrunner.plate_geometry`), equivalent to paper 2 eq. (1): m z̈ = m g − Σ F_j,
J_x φ̈_x = Σ y_j F_j, J_y φ̈_y = −Σ x_j F_j, with F_j the upward force at corner j. Four magnets
F_j = i_j² / d_j(h_j)² with d_j(h) = d_gain_j · λ^(−1/2) · (h + d_offset) (eq. (2), Sec. 3.2.3), so
the plate is open-loop unstable: the force grows as the gap shrinks.

Unmodelled effects that make the twin look like the test bed (paper 2 Remark 1, Remark 9):

* contact: four screws hold the plate at the gap ``screw_gap`` (5.5 mm) until the magnets lift it,
  and a stop at ``top_gap`` keeps it off the yokes — stiff, damped, one-sided springs at the corners;
* magnetic saturation: no magnet pulls more than ``force_max``;
* per-magnet deviations of the force model, ``d_gain_j`` (Fig. 3: the identified d_j differ);
* a lightly damped plate mode at ``mode_omega`` ≈ 942 rad/s, a bending mode with amplitude 1 at the
  four magnets and ``mode_sensor_shape`` at the sensors, excited by the corner forces;
* current ripple (white, per magnet, held over a sample) and sensor noise (white, per sensor).

Outputs are the four sensor readings y_1..y_4 [m]; inputs the four currents i_1..i_4 [A] ∈ [0, 8].
Generalised coordinates x = (z, φ_x, φ_y, q) with q the mode; the gaps are h = x G and the corner
forces act through −G (virtual work). Integration: drift-kick-drift (position Verlet: second
order for the position-dependent forces, one force evaluation per sub-step; the damping and
contact forces see the velocity at the sub-step's start) with the input held over the sample
(zero-order hold), sub-steps no longer than ``max_substep`` [s]. The contact stiffness is set per
run from the lightest corner mass so that the stiffest contact motion has ``contact_omega`` and
``contact_zeta`` whatever the inertia; with ω·h ≤ 0.64 the scheme is stable for every allowed
parameter (tests/test_plate_twin.py checks the spectral radius, and that the twin steps by it).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from labrunner._ufunc import clip, count_nonzero
from labrunner.errors import InvalidParameter
from labrunner.plate_geometry import LAMBDA_INV_SQRT, PlateGeometry
from labrunner.rigs.base import Derived, RigConfig, RigInfo, Signal
from labrunner.rigs.schema import Param
from labrunner.rigs.sim import SimRig
from labrunner.rigs.sim._integrate import substeps
from labrunner.rigs.sim._noise import NoiseStreams

_POS = {"lo": 0.0, "lo_open": True}
#: Parameters that shape the shared matrices; a campaign cannot vary them per run.
GEOMETRY = ("l_dx", "l_dy", "l_fx", "l_fy", "mode_sensor_shape", "i_max", "max_substep")


class PlateTwin(SimRig):
    """Batch twin of the magnetically supported plate; inputs ``i1..i4`` [A], outputs ``y1..y4`` [m]."""

    KIND = "plate"
    PARAMETERS = {
        "m": Param(4.69, "kg", "plate mass (paper 2 Table 2)", lo=0.5, hi=50.0),
        "J_x": Param(5.13e-2, "kg m^2", "moment of inertia about x_b (Table 2)", lo=1e-3, hi=5.0),
        "J_y": Param(8.19e-2, "kg m^2", "moment of inertia about y_b (Table 2)", lo=1e-3, hi=5.0),
        "g": Param(9.81, "m/s^2", "gravitational acceleration (Table 2)", lo=0.0, hi=20.0),
        "l_dx": Param(0.135, "m", "sensor distance in x (Table 2)", **_POS),
        "l_dy": Param(0.144, "m", "sensor distance in y (Table 2)", **_POS),
        "l_fx": Param(0.1825, "m", "force-point distance in x (Table 2)", **_POS),
        "l_fy": Param(0.117, "m", "force-point distance in y (Table 2)", **_POS),
        "lambda_inv_sqrt": Param(
            LAMBDA_INV_SQRT, "A s/(kg m^3)^0.5", "d(h) = λ^(−1/2) h (Sec. 3.2.3, Fig. 3)", lo=50.0, hi=1000.0
        ),
        **{
            f"d_gain_{j}": Param(
                1.0, "1", f"factor on d_{j}(h) of magnet {j} (identified d_j differ, Fig. 3)", lo=0.5, hi=2.0
            )
            for j in range(1, 5)
        },
        "d_offset": Param(0.0, "m", "gap offset of the force model d(h) = λ^(−1/2)(h + offset)", lo=-2e-4, hi=2e-3),
        "force_max": Param(
            300.0, "N", "magnetic saturation: the largest force of one magnet (assumed)", lo=50.0, hi=1e4
        ),
        "i_max": Param(8.0, "A", "current limit of the power electronics (Sec. 4)", lo=0.1, hi=50.0),
        "screw_gap": Param(5.5e-3, "m", "gap at which the screws hold the plate at rest (Sec. 4.1)", lo=1e-3, hi=20e-3),
        "top_gap": Param(0.5e-3, "m", "gap of the upper mechanical stop (assumed)", lo=1e-4, hi=1e-3),
        "contact_omega": Param(
            1e4, "rad/s", "eigenfrequency of the stiffest contact motion (numerical stiffness)", lo=1e3, hi=2e4
        ),
        "contact_zeta": Param(0.5, "1", "damping ratio of that contact motion", lo=0.0, hi=1.0),
        "mode_omega": Param(942.0, "rad/s", "plate resonance (paper 2 Remark 9, Sec. 4.2)", lo=100.0, hi=5000.0),
        "mode_zeta": Param(0.02, "1", "damping ratio of the plate mode (assumed: lightly damped)", lo=0.0, hi=1.0),
        "mode_mass": Param(
            4.0, "kg", "modal mass of the plate mode (assumed: notch needed, Remark 9)", lo=0.05, hi=100.0
        ),
        "mode_sensor_shape": Param(0.8, "1", "mode amplitude at the sensors relative to the magnets", lo=-2.0, hi=2.0),
        "max_substep": Param(32e-6, "s", "longest integration sub-step (stability: ω h ≤ 0.64)", lo=1e-7, hi=32e-6),
    }
    NOISE = {
        "sensor_std": Param(
            0.5e-6, "m", "white sensor noise, std (assumed; Sec. 4.3.1: RMS spread < 30 nm)", lo=0.0, hi=1e-4
        ),
        "current_std": Param(0.02, "A", "current ripple of the current controllers, std (assumed)", lo=0.0, hi=1.0),
    }

    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        p = super().validate_parameters(raw, path)
        if p["top_gap"] >= p["screw_gap"]:
            raise InvalidParameter(
                f"{path}.top_gap", f"must be < screw_gap = {p['screw_gap']:g} m, got {p['top_gap']:g}"
            )
        return p

    @classmethod
    def check_overrides(
        cls, config: RigConfig, overrides: Mapping[str, Any], batch: int, path: str = "overrides"
    ) -> dict[str, np.ndarray]:
        fixed = sorted(set(overrides) & set(GEOMETRY))
        if fixed:
            raise InvalidParameter(f"{path}.{fixed[0]}", f"cannot vary per run; fixed: {', '.join(GEOMETRY)}")
        p = super().check_overrides(config, overrides, batch, path)
        bad = p["top_gap"] >= p["screw_gap"]
        if bad.any():
            raise InvalidParameter(f"{path}.top_gap", f"must be < screw_gap = {p['screw_gap'][bad][0]:g} m")
        return p

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        p = {**{k: v.default for k, v in cls.PARAMETERS.items()}, **parameters}
        constants = {
            k: float(p[k]) for k in ("m", "g", "J_x", "J_y", "l_dx", "l_dy", "l_fx", "l_fy", "lambda_inv_sqrt")
        }
        K = PlateGeometry(**{k: float(p[k]) for k in ("l_dx", "l_dy", "l_fx", "l_fy")}).K  # h = K y_1..3, eq. (4)
        return RigInfo(
            name=name,
            kind=cls.KIND,
            inputs=tuple(Signal(f"i{j}", "A", 0.0, float(p["i_max"])) for j in range(1, 5)),
            outputs=tuple(Signal(f"y{j}", "m", 0.0, 10e-3, resolution=5e-6) for j in range(1, 5)),
            fs_range=(1000.0, 100_000.0),
            fs_default=32_000.0,
            safe_input=(0.0, 0.0, 0.0, 0.0),
            constants={**constants, "rest_gap": float(p["screw_gap"])},
            simulated=True,
            description=description
            or "simulated magnetically supported plate (paper 2): 3-DOF body, four magnets, 942 rad/s mode",
            derived=tuple(Derived(f"h{j + 1}", "m", (*map(float, K[j]), 0.0)) for j in range(4)),
        )

    # -- Rig hooks -------------------------------------------------------------------------------
    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        p = self.per_run(batch, overrides)
        self.p = p
        c = self.config.parameters
        self.geometry = PlateGeometry(m=float(c["m"]), g=float(c["g"]), J_x=float(c["J_x"]), J_y=float(c["J_y"]),
                                      l_dx=float(c["l_dx"]), l_dy=float(c["l_dy"]), l_fx=float(c["l_fx"]), l_fy=float(c["l_fy"]))  # fmt: skip
        # generalised coordinates (z, φ_x, φ_y, q) → gaps at the magnets (columns) and at the sensors
        self._G = np.vstack([self.geometry.magnet_matrix.T, np.ones(4)])
        self._S = np.vstack([self.geometry.sensor_matrix.T, np.full(4, float(c["mode_sensor_shape"]))])
        self.substeps = substeps(self.fs, float(c["max_substep"]))
        h = 1.0 / (self.fs * self.substeps)
        self._h_steps = np.array(h), np.array(0.5 * h)
        col = lambda v: np.asarray(v, dtype=float)[:, None]  # noqa: E731 - (B,) → (B, 1)
        full = lambda v: np.array(np.broadcast_to(col(v), (batch, 4)))  # noqa: E731 - (B,) → (B, 4): equal shapes are cheaper per tick
        gains = np.column_stack([p[f"d_gain_{j}"] for j in range(1, 5)])
        self._lam = col(p["lambda_inv_sqrt"]) * gains  # (B, 4)
        self._inv_mass = 1.0 / np.column_stack([p["m"], p["J_x"], p["J_y"], p["mode_mass"]])  # (B, 4)
        self._gravity = np.column_stack([p["g"], np.zeros((batch, 3))])
        self._stiff = np.zeros((batch, 4))  # the mode's own stiffness and damping, acting on q only
        self._damp = np.zeros((batch, 4))
        self._stiff[:, 3] = p["mode_omega"] ** 2
        self._damp[:, 3] = 2.0 * p["mode_zeta"] * p["mode_omega"]
        # one stop's stiffness and damping from the lightest corner mass 1/λ_max(Gᵀ M⁻¹ G)
        corner_mass = 1.0 / np.linalg.eigvalsh(np.einsum("ja,ba,ak->bjk", self._G.T, self._inv_mass, self._G))[:, -1]
        self._k_c = full(corner_mass * p["contact_omega"] ** 2)
        self._c_c = full(2.0 * p["contact_zeta"] * corner_mass * p["contact_omega"])
        self._screw, self._top = full(p["screw_gap"]), full(p["top_gap"])
        self._offset, self._f_max = full(p["d_offset"]), full(p["force_max"])
        self._any_offset = bool(np.any(self._offset))
        # noise drawn pre-scaled: sensors (B, 4) | current ripple (B, 4)
        scale = np.column_stack(
            [np.repeat(col(p["sensor_std"]), 4, axis=1), np.repeat(col(p["current_std"]), 4, axis=1)]
        )
        self._noise = NoiseStreams(seeds, 8, stream=3, block=2048, scale=scale, groups=2)
        self._G_T = self._G.T
        # per-tick scratch, (B, 4) each, one purpose each: the squared currents i², the drift/kick
        # increments (h/2)·v and h·ẍ, the accelerations ẍ; at a position (:meth:`_at_position`): the
        # gaps h = G x, d(h)², the stops' penetration, its sign and k·pen, gravity − the mode's spring;
        # in :meth:`_acceleration`: the upward corner forces, the stops' damped forces, the generalised
        # forces per unit mass and the mode's damping
        scratch = lambda: np.zeros((batch, 4))  # noqa: E731
        self._current_sq, self._increment, self._acc = scratch(), scratch(), scratch()
        self._gaps, self._dd, self._pen, self._pen_sign, self._k_pen, self._lin = (scratch() for _ in range(6))
        self._f_up, self._stop_force, self._gen_acc, self._damping = (scratch() for _ in range(4))
        # at rest on the four screws, sagging: (k G Gᵀ + S) x = M g + k G 1 screw_gap, S the mode's stiffness
        stiffness = self._k_c[:, :1, None] * (self._G @ self._G.T) + np.einsum(
            "bi,ij->bij", self._stiff / self._inv_mass, np.eye(4)
        )
        load = self._gravity / self._inv_mass + self._k_c[:, :1] * self._screw[:, :1] * self._G.sum(axis=1)
        x = np.linalg.solve(stiffness, load[:, :, None])[:, :, 0]
        self.set_state(x, np.zeros((batch, 4)))
        return self._sensors(self._noise.next()[0])

    def set_state(self, x: np.ndarray, v: np.ndarray | None = None) -> None:
        """Put the batch at generalised coordinates ``x`` (B, 4) (and velocities ``v``, default unchanged)."""
        self.x = np.array(np.broadcast_to(x, (self.batch, 4)), dtype=float)
        if v is not None:
            self.v = np.array(np.broadcast_to(v, (self.batch, 4)), dtype=float)

    def _step(self, u: np.ndarray) -> np.ndarray:
        sensor_noise, current_noise = self._noise.next()
        cs, acc, inc, x, v = self._current_sq, self._acc, self._increment, self.x, self.v
        np.add(u, current_noise, out=cs)  # the currents with their ripple, squared
        np.maximum(cs, 0.0, out=cs)
        np.square(cs, out=cs)
        h, half = self._h_steps  # 0-d arrays: cheaper in a ufunc than Python floats
        for _ in range(self.substeps):  # drift-kick-drift (position Verlet): one evaluation per sub-step
            np.multiply(half, v, out=inc)  # x += (h/2) v
            np.add(x, inc, out=x)
            self._at_position()
            self._acceleration(cs, v, out=acc)
            np.multiply(h, acc, out=inc)  # v += h ẍ(x)
            np.add(v, inc, out=v)
            np.multiply(half, v, out=inc)  # x += (h/2) v
            np.add(x, inc, out=x)
        return self._sensors(sensor_noise)

    # -- model -----------------------------------------------------------------------------------
    @property
    def pose(self) -> np.ndarray:
        """(B, 3) rigid pose (z [m], φ_x [rad], φ_y [rad])."""
        return self.x[:, :3].copy()

    def magnet_gaps(self) -> np.ndarray:
        """(B, 4) air gaps h_j at the yoke centres [m], rigid pose plus the plate mode."""
        return self.x @ self._G

    def magnet_forces(self, current_sq: np.ndarray, gaps: np.ndarray) -> np.ndarray:
        """(B, 4) magnet forces [N] for squared currents [A²] at ``gaps`` (eq. (2), saturated)."""
        return self._forces(current_sq, self._d_squared(gaps, np.empty(np.shape(gaps))), np.empty(np.shape(gaps)))

    def _d_squared(self, gaps: np.ndarray, out: np.ndarray) -> np.ndarray:
        """d_j(h_j)² of eq. (2), d = λ^(−1/2)·d_gain·(h + offset), h kept above 1 µm."""
        if self._any_offset:
            np.add(gaps, self._offset, out=out)
            np.maximum(out, 1e-6, out=out)
        else:  # h + 0 is h (the bound removes a −0)
            np.maximum(gaps, 1e-6, out=out)
        np.multiply(self._lam, out, out=out)
        return np.multiply(out, out, out=out)

    def _forces(self, current_sq: np.ndarray, dd: np.ndarray, out: np.ndarray) -> np.ndarray:
        """i²/d² limited to ``force_max`` (magnetic saturation)."""
        np.divide(current_sq, dd, out=out)
        return np.minimum(out, self._f_max, out=out)

    def _at_position(self) -> None:
        """What depends only on x, for the accelerations at it: gaps, d², the stops, the mode's spring.

        A corner below the screws (gap > screw_gap) or above the stop (gap < top_gap) has the
        penetration pen = gap − clip(gap, top, screw) (> 0 below, < 0 above) and pushes back with
        sign(pen)·max(sign(pen)·(k pen + c ṗ), 0): a one-sided spring-damper (:meth:`_acceleration`).
        """
        gaps, pen = self._gaps, self._pen
        np.dot(self.x, self._G, out=gaps)  # h = G x
        self._d_squared(gaps, self._dd)
        np.subtract(gaps, clip(gaps, self._top, self._screw, out=pen), out=pen)  # pen = h − clip(h, top, screw)
        self._contact = bool(count_nonzero(pen))  # any corner on a stop?
        if self._contact:
            np.sign(pen, out=self._pen_sign)
            np.multiply(self._k_c, pen, out=self._k_pen)
        # gravity minus the mode's spring: gravity acts on z only, the spring on q only, so
        # (gravity − F) − spring = (gravity − spring) − F exactly, and one subtraction moves here
        np.multiply(self._stiff, self.x, out=self._lin)
        np.subtract(self._gravity, self._lin, out=self._lin)

    def _acceleration(self, current_sq: np.ndarray, v: np.ndarray, out: np.ndarray) -> np.ndarray:
        """(B, 4) ẍ at the current x (see :meth:`_at_position`) for squared currents and velocity ``v``."""
        f_up, stop, gen, damping = self._f_up, self._stop_force, self._gen_acc, self._damping
        self._forces(current_sq, self._dd, f_up)  # i²/d(h)², eq. (2)
        if self._contact:  # f_up += s·max(s·(k pen + c ḣ), 0), s = sign(pen), ḣ = G v
            s = self._pen_sign
            np.dot(v, self._G, out=stop)
            np.multiply(self._c_c, stop, out=stop)
            np.add(self._k_pen, stop, out=stop)
            np.multiply(s, stop, out=stop)
            np.maximum(stop, 0.0, out=stop)
            np.multiply(s, stop, out=stop)
            np.add(f_up, stop, out=f_up)
        np.dot(f_up, self._G_T, out=gen)  # generalised forces of the upward corner forces, per unit mass
        np.multiply(gen, self._inv_mass, out=gen)
        np.subtract(self._lin, gen, out=out)  # ẍ = (gravity − spring) − M⁻¹ Gᵀ f − damping·v
        np.multiply(self._damp, v, out=damping)
        return np.subtract(out, damping, out=out)

    def _sensors(self, noise: np.ndarray) -> np.ndarray:
        """The four sensor readings (a new array) with their (pre-scaled) noise."""
        y = np.dot(self.x, self._S)
        return np.add(y, noise, out=y)
