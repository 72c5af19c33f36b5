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
* a lightly damped plate mode at ``mode_omega`` ≈ 942 rad/s, excited by the corner forces and seen
  by the sensors (shapes ``mode_force_shape`` / ``mode_sensor_shape``, amplitudes at the corners);
* current ripple (white, per magnet, held over a sample) and sensor noise (white, per sensor).

Outputs are the four sensor readings y_1..y_4 [m]; inputs the four currents i_1..i_4 [A] ∈ [0, 8].
Generalised coordinates x = (z, φ_x, φ_y, q) with q the mode; the gaps are h = x G and the corner
forces act through −G (virtual work). Integration: semi-implicit Euler with the input held over
the sample (zero-order hold), sub-steps no longer than ``max_step`` [s].
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter, check_finite
from labrunner.plate_geometry import LAMBDA_INV_SQRT, PlateGeometry
from labrunner.rigs.base import Faults, Rig, RigInfo, Signal


@dataclass(frozen=True)
class _Spec:
    default: float
    lo: float
    hi: float
    doc: str


#: Scalar parameters: default, allowed range and meaning. Every one may be overridden per run.
PARAMETERS: dict[str, _Spec] = {
    "m": _Spec(4.69, 0.5, 50.0, "plate mass [kg] (Table 2)"),
    "J_x": _Spec(5.13e-2, 1e-3, 5.0, "moment of inertia about x_b [kg m²] (Table 2)"),
    "J_y": _Spec(8.19e-2, 1e-3, 5.0, "moment of inertia about y_b [kg m²] (Table 2)"),
    "g": _Spec(9.81, 0.0, 20.0, "gravitational acceleration [m/s²]"),
    "lambda_inv_sqrt": _Spec(LAMBDA_INV_SQRT, 50.0, 1000.0, "λ^(−1/2) of d(h) = λ^(−1/2)·h [A s/(kg m³)^(1/2)]"),
    "d_offset": _Spec(0.0, -2e-4, 2e-3, "gap offset of the force model d(h) [m]"),
    "force_max": _Spec(300.0, 50.0, 1e4, "saturation force of one magnet [N]"),
    "screw_gap": _Spec(5.5e-3, 1e-3, 20e-3, "gap at which the screws hold the plate [m]"),
    "top_gap": _Spec(0.5e-3, 1e-4, 1e-3, "gap of the upper mechanical stop [m]"),
    "contact_omega": _Spec(1e4, 1e3, 2e4, "eigenfrequency of the stiffest contact motion [rad/s]"),
    "contact_zeta": _Spec(0.5, 0.0, 1.0, "damping ratio of that contact motion"),
    "mode_omega": _Spec(942.0, 100.0, 5000.0, "eigenfrequency of the plate mode [rad/s] (Remark 9)"),
    "mode_zeta": _Spec(0.02, 0.0, 1.0, "damping ratio of the plate mode"),
    "mode_mass": _Spec(4.0, 0.05, 100.0, "modal mass of the plate mode [kg]"),
    "sensor_std": _Spec(0.5e-6, 0.0, 1e-4, "sensor noise, standard deviation [m]"),
    "current_std": _Spec(0.02, 0.0, 1.0, "current ripple, standard deviation [A]"),
}
#: Per-magnet and per-sensor vectors (not overridable per run).
VECTORS: dict[str, tuple[tuple[float, ...], str]] = {
    "d_gain": ((1.0, 1.0, 1.0, 1.0), "per-magnet factor on d_j(h)"),
    "mode_force_shape": ((1.0, 1.0, 1.0, 1.0), "plate-mode amplitude at the four magnets"),
    "mode_sensor_shape": ((0.8, 0.8, 0.8, 0.8), "plate-mode amplitude at the four sensors"),
}
GEOMETRY = ("l_dx", "l_dy", "l_fx", "l_fy")
NOISE = ("sensor_std", "current_std")
_NOISE_BLOCK = 2048  # samples of noise drawn per run at a time (a loop per block, never per tick)


def plate_info(name: str = "plate-sim", i_max: float = 8.0) -> RigInfo:
    """Signals and nominal constants of the plate (paper 2 Sec. 4: currents 0–8 A, 32 kHz)."""
    g = PlateGeometry()
    constants = {k: getattr(g, k) for k in ("m", "g", "J_x", "J_y", *GEOMETRY)}
    return RigInfo(
        name=name,
        kind="plate",
        inputs=tuple(Signal(f"i{j}", "A", 0.0, i_max) for j in range(1, 5)),
        outputs=tuple(Signal(f"y{j}", "m", 0.0, 10e-3, resolution=5e-6) for j in range(1, 5)),
        fs_range=(1000.0, 100_000.0),
        fs_default=32_000.0,
        safe_input=(0.0, 0.0, 0.0, 0.0),
        constants={**constants, "lambda_inv_sqrt": LAMBDA_INV_SQRT, "rest_gap": PARAMETERS["screw_gap"].default},
        simulated=True,
        description="Simulated magnetically supported plate (paper 2): rigid 3-DOF body, four magnets, 942 rad/s mode",
    )


class PlateTwin(Rig):
    """Batch twin of the magnetically supported plate; see the module docstring for the model.

    ``parameters`` takes the keys of :data:`PARAMETERS` (except the noise), :data:`VECTORS` and
    :data:`GEOMETRY`; ``noise`` takes :data:`NOISE`. Unknown keys raise :class:`InvalidParameter`.
    Per-run overrides in :meth:`reset` accept every key of :data:`PARAMETERS` (NaN: keep nominal).
    """

    def __init__(
        self,
        parameters: Mapping[str, object] | None = None,
        noise: Mapping[str, object] | None = None,
        *,
        faults: Faults | None = None,
        name: str = "plate-sim",
        i_max: float = 8.0,
        max_step: float = 32e-6,
    ) -> None:
        params = dict(parameters or {})
        self.geometry = PlateGeometry(**{k: check_finite(f"parameters.{k}", params.pop(k)) for k in GEOMETRY if k in params})
        self.vectors = {k: _check_vector(f"parameters.{k}", params.pop(k, d), positive=k == "d_gain") for k, (d, _) in VECTORS.items()}
        scalars = {k: s.default for k, s in PARAMETERS.items()}
        for section, values, allowed in (
            ("parameters", params, sorted(set(PARAMETERS) - set(NOISE))),
            ("noise", dict(noise or {}), list(NOISE)),
        ):
            for key, value in values.items():
                if key not in allowed:
                    extra = sorted(set(VECTORS) | set(GEOMETRY)) if section == "parameters" else []
                    raise InvalidParameter(f"{section}.{key}", f"unknown key; allowed: {', '.join(allowed + extra)}")
                scalars[key] = _check_range(f"{section}.{key}", value, PARAMETERS[key])
        if scalars["top_gap"] >= scalars["screw_gap"]:
            raise InvalidParameter("parameters.top_gap", f"must be < screw_gap = {scalars['screw_gap']}, got {scalars['top_gap']}")
        if not (1e-7 <= check_finite("max_step", max_step) <= 1e-3):
            raise InvalidParameter("max_step", f"must be in [1e-07, 0.001] s, got {max_step!r}")
        self.nominal = scalars
        self.max_step = float(max_step)
        geo = self.geometry
        # generalised coordinates (z, φ_x, φ_y, q) → gaps at the magnets (columns) and at the sensors
        self._G = np.vstack([geo.magnet_matrix.T, self.vectors["mode_force_shape"]])  # (4 coords, 4 magnets)
        self._S = np.vstack([geo.sensor_matrix.T, self.vectors["mode_sensor_shape"]])  # (4 coords, 4 sensors)
        super().__init__(plate_info(name, i_max), faults)

    # -- Rig hooks -------------------------------------------------------------------------------
    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        p = {k: np.full(batch, v) for k, v in self.nominal.items()}
        for key, values in overrides.items():
            if key not in PARAMETERS:
                raise InvalidParameter(f"rig_parameters.{key}", f"not overridable per run; allowed: {', '.join(PARAMETERS)}")
            values = np.broadcast_to(np.asarray(values, dtype=float), (batch,))
            given = ~np.isnan(values)
            for v in values[given]:
                _check_range(f"rig_parameters.{key}", v, PARAMETERS[key])
            p[key] = np.where(given, values, p[key])
        self.p = p
        self.substeps = max(1, math.ceil(1.0 / (self.fs * self.max_step) - 1e-9))
        col = lambda v: np.asarray(v, dtype=float)[:, None]  # noqa: E731 - (B,) → (B, 1)
        self._lam = col(p["lambda_inv_sqrt"]) * self.vectors["d_gain"]  # (B, 4)
        self._inv_mass = 1.0 / np.column_stack([p["m"], p["J_x"], p["J_y"], p["mode_mass"]])  # (B, 4)
        self._gravity = np.column_stack([p["g"], np.zeros((batch, 3))])
        stiff = np.zeros((batch, 4))  # the mode's own stiffness and damping, acting on q only
        damp = np.zeros((batch, 4))
        stiff[:, 3] = p["mode_omega"] ** 2
        damp[:, 3] = 2.0 * p["mode_zeta"] * p["mode_omega"]
        self._stiff, self._damp = stiff, damp
        # one stop's stiffness and damping from the lightest corner mass 1/λ_max(Gᵀ M⁻¹ G), so that the
        # stiffest contact motion has exactly contact_omega and contact_zeta whatever the inertia
        corner_mass = 1.0 / np.linalg.eigvalsh(np.einsum("ja,ba,ak->bjk", self._G.T, self._inv_mass, self._G))[:, -1]
        self._k_c = col(corner_mass * p["contact_omega"] ** 2)
        self._c_c = col(2.0 * p["contact_zeta"] * corner_mass * p["contact_omega"])
        self._screw, self._top = col(p["screw_gap"]), col(p["top_gap"])
        self._offset, self._f_max = col(p["d_offset"]), col(p["force_max"])
        self._sensor_std, self._current_std = col(p["sensor_std"]), col(p["current_std"])
        self._rngs = [np.random.default_rng(int(s)) for s in seeds]
        self._noise = np.zeros((batch, 0, 8))
        self._noise_k = 0
        # at rest on the screws: each corner carries a quarter of the weight
        self.x = np.zeros((batch, 4))
        self.x[:, 0] = p["screw_gap"] + p["m"] * p["g"] / (4.0 * self._k_c[:, 0])
        self.v = np.zeros((batch, 4))
        return self._sensors(self._draw()[:, :4])

    def _step(self, u: np.ndarray) -> np.ndarray:
        noise = self._draw()
        current_sq = np.maximum(u + self._current_std * noise[:, 4:], 0.0) ** 2
        h = 1.0 / (self.fs * self.substeps)
        for _ in range(self.substeps):
            self._substep(current_sq, h)
        return self._sensors(noise[:, :4])

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
        d = self._lam * np.maximum(gaps + self._offset, 1e-6)
        return np.minimum(current_sq / (d * d), self._f_max)

    def _substep(self, current_sq: np.ndarray, h: float) -> None:
        gaps = self.x @ self._G
        f_up = self.magnet_forces(current_sq, gaps)
        if (gaps > self._screw).any() or (gaps < self._top).any():
            rate = self.v @ self._G
            below = gaps - self._screw
            above = self._top - gaps
            f_up += np.where(below > 0, np.maximum(self._k_c * below + self._c_c * rate, 0.0), 0.0)
            f_up -= np.where(above > 0, np.maximum(self._k_c * above - self._c_c * rate, 0.0), 0.0)
        acc = self._gravity - (f_up @ self._G.T) * self._inv_mass - self._stiff * self.x - self._damp * self.v
        self.v += h * acc
        self.x += h * self.v

    def _sensors(self, noise: np.ndarray) -> np.ndarray:
        return self.x @ self._S + self._sensor_std * noise

    def _draw(self) -> np.ndarray:
        """(B, 8) standard normal noise of this sample (4 sensors, 4 currents), one stream per run."""
        if self._noise_k >= self._noise.shape[1]:
            self._noise = np.stack([rng.standard_normal((_NOISE_BLOCK, 8)) for rng in self._rngs])
            self._noise_k = 0
        self._noise_k += 1
        return self._noise[:, self._noise_k - 1]


def _check_range(field: str, value: object, spec: _Spec) -> float:
    v = check_finite(field, value)
    if not spec.lo <= v <= spec.hi:
        raise InvalidParameter(field, f"must be in [{spec.lo:g}, {spec.hi:g}] ({spec.doc}), got {v:g}")
    return v


def _check_vector(field: str, value: object, positive: bool) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidParameter(field, f"must be a list of 4 numbers, got {value!r}") from None
    if arr.shape != (4,) or not np.all(np.isfinite(arr)) or (positive and np.any(arr <= 0)):
        kind = "finite positive" if positive else "finite"
        raise InvalidParameter(field, f"must be a list of 4 {kind} numbers, got {value!r}")
    return arr
