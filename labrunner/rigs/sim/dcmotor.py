"""Twin of the thesis's DC motor test bed (thesis Sec. 2.4.1 and 3.1-3.3): voltage u → load angle θ.

Plant, per run (thesis (2.31) with the unmodelled effects that η stands for made explicit)::

    θ̇_m = Ω
    Ω̇   = −a Ω + b (v − F)                      (2.31b), v the voltage acting on the motor
    v    = sat(u + n_u)  or  τ_e v̇ = sat(u + n_u) − v   (optional electrical lag L/R, from (2.30))
    F    = u_c sign(Ω) when moving; sticks at Ω = 0 while |v| ≤ u_s  (Coulomb + static friction)
    θ    = play(θ_m, backlash)                   (gearbox backlash between drive and load)
    y    = Δ · round(θ / Δ),  Δ = 2π / encoder_counts   (11-bit incremental encoder, Sec. 3.1)

Friction is given as voltages (the voltage needed to break away / to keep moving), so that an input
below ``static_friction`` does not move the load: the thesis's "white circle" runs (Fig. 3.10).
The encoder is zeroed at the start in the middle of a count (round, not floor): motions smaller
than Δ/2 either way are invisible. ``n_u`` is white voltage noise held over each sample
(driver ripple, torque ripple).

Integration: ``u`` is held over the sample; ``n_sub`` sub-steps of at most ``max_substep`` [s]
each use the exact ZOH transition of the linear part (θ_m, Ω, v) with the friction force held over
the sub-step; a velocity that would reverse under Coulomb friction stops at zero and the
stick/breakaway test (on the voltage reached at the end of the sub-step) runs again at the next. The error of that event handling is below
|Ω̇| h² / 2 in θ (≈ 1e-3 rad at 12 V and h = 1.25 ms, under the encoder's Δ = 3.1e-3 rad).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigConfig, RigInfo, Signal
from labrunner.rigs.schema import Param
from labrunner.rigs.sim import SimRig
from labrunner.rigs.sim._integrate import substeps, zoh_discretise
from labrunner.rigs.sim._noise import NoiseStreams

_POS = {"lo": 0.0, "lo_open": True}


class DCMotorTwin(SimRig):
    """Batched twin of the DC motor with gearbox, load and encoder; input ``u`` [V], output ``theta`` [rad]."""

    KIND = "dcmotor"
    PARAMETERS = {
        "a": Param(39.44, "1/s", "pole of (2.31b), identified in thesis Sec. 3.2", **_POS),
        "b": Param(108.55, "rad/(V s^2)", "input gain of (2.31b), identified in thesis Sec. 3.2", **_POS),
        "u_max": Param(12.0, "V", "driver saturation ±u_max (MD10C on a 12 V supply, thesis Sec. 3.1)", **_POS),
        "static_friction": Param(0.8, "V", "breakaway voltage of motor+gearbox (assumed; 1:18 spur gearbox)", lo=0.0),
        "coulomb_friction": Param(0.6, "V", "voltage that keeps the load moving (assumed), <= static", lo=0.0),
        "backlash": Param(0.02, "rad", "gearbox play at the load, about 1.1 deg (assumed)", lo=0.0),
        "electrical_tau": Param(0.5e-3, "s", "electrical time constant L/R of (2.26); 0 disables (assumed)", lo=0.0),
        "encoder_counts": Param(2048, "1/rev", "encoder counts per turn, 2 x 10 bit (thesis Sec. 3.1); 0: ideal", lo=0),
        "max_substep": Param(1.25e-3, "s", "longest integration sub-step", lo=1e-6, hi=0.1),
    }
    NOISE = {
        "input_v": Param(0.02, "V", "std of white voltage noise held over each sample (assumed)", lo=0.0),
    }

    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        p = super().validate_parameters(raw, path)
        _check_friction(np.array([p["static_friction"]]), np.array([p["coulomb_friction"]]), f"{path}.coulomb_friction")
        return p

    @classmethod
    def check_overrides(
        cls, config: RigConfig, overrides: Mapping[str, Any], batch: int, path: str = "overrides"
    ) -> dict[str, np.ndarray]:
        p = super().check_overrides(config, overrides, batch, path)
        _check_friction(p["static_friction"], p["coulomb_friction"], f"{path}.coulomb_friction")
        return p

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        p = {**{k: v.default for k, v in cls.PARAMETERS.items()}, **parameters}
        counts = int(p["encoder_counts"])
        dtheta = 2.0 * np.pi / counts if counts else 0.0
        return RigInfo(
            name=name,
            kind=cls.KIND,
            inputs=(Signal("u", "V", -p["u_max"], p["u_max"]),),
            outputs=(Signal("theta", "rad", resolution=dtheta),),
            fs_range=(10.0, 10_000.0),
            fs_default=200.0,
            safe_input=(0.0,),
            constants={"a": p["a"], "b": p["b"], "rho": p["b"], "u_max": p["u_max"], "dtheta": dtheta},
            simulated=True,
            description=description or "simulated DC motor with gearbox, load and encoder (thesis Sec. 2.4.1)",
        )

    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        p = self.per_run(batch, overrides)
        self.p = p
        self.n_sub = substeps(self.fs, float(p["max_substep"].min()))
        h = 1.0 / (self.fs * self.n_sub)
        self._lag = p["electrical_tau"] > 0.0
        # one matrix exponential per distinct (a, b, τ_e), not per run
        rows, inverse = np.unique(np.stack([p["a"], p["b"], p["electrical_tau"]], axis=1), axis=0, return_inverse=True)
        a, b, tau = rows.T
        lag = tau > 0.0
        inv_tau = np.where(lag, 1.0 / np.where(lag, tau, 1.0), 0.0)
        A = np.zeros((len(rows), 3, 3))
        Bm = np.zeros((len(rows), 3, 2))  # inputs w = (commanded voltage, friction voltage)
        A[:, 0, 1] = 1.0
        A[:, 1, 1] = -a
        A[:, 1, 2] = np.where(lag, b, 0.0)
        A[:, 2, 2] = -inv_tau
        Bm[:, 1, 0] = np.where(lag, 0.0, b)
        Bm[:, 1, 1] = -b
        Bm[:, 2, 0] = inv_tau
        Phi, Gam = zoh_discretise(A, Bm, h)
        Phi, Gam = Phi[inverse.reshape(-1)], Gam[inverse.reshape(-1)]
        # transition over one sub-step, laid out (3, 5, B) for z = (θ_m, Ω, v, v_cmd, F) of shape (5, B)
        self._M = np.ascontiguousarray(np.concatenate([Phi, Gam], axis=2).transpose(1, 2, 0))
        self._z = np.zeros((5, batch))
        self._theta = np.zeros(batch)  # load angle behind the backlash [rad]
        self._half_play = 0.5 * p["backlash"]
        self._coulomb = p["coulomb_friction"] > 0.0
        self._static = p["static_friction"] > 0.0
        counts = p["encoder_counts"]
        self._dtheta = np.where(counts > 0, 2.0 * np.pi / np.where(counts > 0, counts, 1.0), 0.0)
        self._noise = NoiseStreams(seeds, 1, stream=1)
        return self._measure_theta()[:, None]

    def _step(self, u: np.ndarray) -> np.ndarray:
        p = self.p
        v = u[:, 0]
        if np.any(p["input_v"] > 0.0):
            v = v + p["input_v"] * self._noise.next()[:, 0]
        v = np.clip(v, -p["u_max"], p["u_max"])
        us, uc = p["static_friction"], p["coulomb_friction"]
        z, M, theta, half = self._z, self._M, self._theta, self._half_play
        z[3] = v
        any_lag, any_coulomb = bool(self._lag.any()), bool(self._coulomb.any())
        for _ in range(self.n_sub):
            # voltage on the motor at the end of the sub-step (the lag's row does not involve θ, Ω, F)
            drive = np.where(self._lag, M[2, 2] * z[2] + M[2, 3] * v, v) if any_lag else v
            stuck = z[1] == 0.0
            hold = None
            if stuck.any():
                s = np.sign(z[1] + stuck * drive)  # direction of motion, or of breakaway when stuck
                hold = stuck & self._static & (np.abs(drive) <= us)
            else:
                s = np.sign(z[1])
            np.multiply(uc, s, out=z[4])
            xn = (M * z[None]).sum(axis=1)
            stop = (xn[1] * s < 0.0) & self._coulomb if any_coulomb else None
            if hold is not None:
                stop = hold if stop is None else stop | hold
                xn[0] = np.where(hold, z[0], xn[0])
            if stop is not None:
                xn[1] *= ~stop
            z[:3] = xn
            theta = np.minimum(np.maximum(theta, z[0] - half), z[0] + half)  # play(theta, θ_m, backlash)
        self._theta = theta
        return self._measure_theta()[:, None]

    def _measure_theta(self) -> np.ndarray:
        d = self._dtheta
        return np.where(d > 0.0, np.round(self._theta / np.where(d > 0.0, d, 1.0)) * d, self._theta)

    @property
    def state(self) -> dict[str, np.ndarray]:
        """True (unmeasured) state per run: load angle [rad], velocity [rad/s], motor voltage [V]."""
        return {"theta": self._theta.copy(), "omega": self._z[1].copy(), "voltage": np.where(self._lag, self._z[2], self._z[3])}


def _check_friction(static: np.ndarray, coulomb: np.ndarray, field: str) -> None:
    """Coulomb friction cannot exceed static friction (the load would stick while driven)."""
    bad = coulomb > static
    if bad.any():
        raise InvalidParameter(field, f"must be <= static_friction = {static[bad][0]:g} V, got {coulomb[bad][0]:g}")
