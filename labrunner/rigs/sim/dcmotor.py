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

Calibration: ``a``, ``b`` are the physical constants of the twin; ``identified_a``, ``identified_b``
are what the thesis's identification (Sec. 3.2) returned on the real motor and are the rig's
constants a, b, ρ (campaign expressions, stability bounds). Friction lowers the identified b
(b_eff ≈ b (1 − u_c/|u|)), so the physical values are chosen such that the thesis's procedure run
on the twin returns the identified ones: 40.8 / 121.3 give 39.43 / 108.52 (seeds 0–4;
docs/rigs.md "Calibration").

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

from labrunner._ufunc import clip, count_nonzero
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
        "a": Param(
            40.8, "1/s", "physical pole of (2.31b), calibrated: thesis Sec. 3.2 on the twin gives 39.44", **_POS
        ),
        "b": Param(
            121.3,
            "rad/(V s^2)",
            "physical input gain of (2.31b), calibrated: Sec. 3.2 on the twin gives 108.55",
            **_POS,
        ),
        "identified_a": Param(39.44, "1/s", "a as thesis Sec. 3.2 identified it: the rig's constant a", **_POS),
        "identified_b": Param(
            108.55, "rad/(V s^2)", "b as thesis Sec. 3.2 identified it: the rig's constants b, rho", **_POS
        ),
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
            constants={
                "a": p["identified_a"],
                "b": p["identified_b"],
                "rho": p["identified_b"],
                "u_max": p["u_max"],
                "dtheta": dtheta,
            },
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
        self._every_run_counts = bool(np.all(counts > 0))
        self._noise = NoiseStreams(seeds, 1, stream=1)
        self._noisy = bool(np.any(p["input_v"] > 0.0))
        # scratch of :meth:`_substep`: the direction s, M·z before its sum, x⁺, s·Ω⁺ and θ_m ± play/2,
        # and the flags "stuck" and "reversed"
        self._s, self._xn, self._ws = np.zeros(batch), np.zeros((3, batch)), np.zeros(batch)
        self._work = np.zeros(self._M.shape)
        self._u_lo = -p["u_max"]
        self._stuck, self._reversed = np.zeros(batch, dtype=bool), np.zeros(batch, dtype=bool)
        return self._measure_theta()[:, None]

    def _step(self, u: np.ndarray) -> np.ndarray:
        p = self.p
        v = u[:, 0]
        if self._noisy:
            v = v + p["input_v"] * self._noise.next()[:, 0]
        z = self._z
        clip(v, self._u_lo, p["u_max"], out=z[3])
        for _ in range(self.n_sub):
            self._substep()
        return self._measure_theta()[:, None]

    def _substep(self) -> None:
        """One sub-step of ``z`` (θ_m, Ω, v, v_cmd, F) and the load angle, in place.

        Fused: the usual sub-step (no run stuck, no velocity reversal) is fourteen array operations into
        scratch arrays; the stick/breakaway and stop tests run only when some run needs them. Same numbers, operation
        for operation, as the plain form (tests/test_rigs_twins.py checks it against a per-run loop).
        """
        z, M, us, uc = self._z, self._M, self.p["static_friction"], self.p["coulomb_friction"]
        s, work, xn = self._s, self._work, self._xn
        stuck = np.equal(z[1], 0.0, out=self._stuck)
        hold = None
        if count_nonzero(stuck):
            # voltage on the motor at the end of the sub-step (the lag's row does not involve θ, Ω, F)
            drive = np.where(self._lag, M[2, 2] * z[2] + M[2, 3] * z[3], z[3])
            np.sign(z[1] + stuck * drive, out=s)  # direction of motion, or of breakaway when stuck
            hold = stuck & self._static & (np.abs(drive) <= us)
        else:
            np.sign(z[1], out=s)
        np.multiply(uc, s, out=z[4])  # F = u_c sign(Ω)
        np.add.reduce(np.multiply(M, z[None], out=work), axis=1, out=xn)  # x⁺ = Φ x + Γ w, w = (v_cmd, F)
        reversed_ = np.less(np.multiply(xn[1], s, out=self._ws), 0.0, out=self._reversed)
        stop = reversed_ & self._coulomb if count_nonzero(reversed_) else None  # Coulomb friction stops a reversal
        if hold is not None:
            stop = hold if stop is None else stop | hold
            xn[0] = np.where(hold, z[0], xn[0])
        if stop is not None:
            xn[1] *= ~stop
        z[:3] = xn
        # play(θ, θ_m, backlash): the load follows once the gap is taken up
        theta = self._theta
        np.maximum(theta, np.subtract(z[0], self._half_play, out=self._ws), out=theta)
        np.minimum(theta, np.add(z[0], self._half_play, out=self._ws), out=theta)

    def _measure_theta(self) -> np.ndarray:
        d = self._dtheta
        if self._every_run_counts:  # the usual case: one encoder for all, no masking
            return np.round(self._theta / d) * d
        return np.where(d > 0.0, np.round(self._theta / np.where(d > 0.0, d, 1.0)) * d, self._theta)

    @property
    def state(self) -> dict[str, np.ndarray]:
        """True (unmeasured) state per run: load angle [rad], velocity [rad/s], motor voltage [V]."""
        return {
            "theta": self._theta.copy(),
            "omega": self._z[1].copy(),
            "voltage": np.where(self._lag, self._z[2], self._z[3]),
        }


def _check_friction(static: np.ndarray, coulomb: np.ndarray, field: str) -> None:
    """Coulomb friction cannot exceed static friction (the load would stick while driven)."""
    bad = coulomb > static
    if bad.any():
        raise InvalidParameter(field, f"must be <= static_friction = {static[bad][0]:g} V, got {coulomb[bad][0]:g}")
