"""Twin of paper 1's pilot-operated proportional flow valve with its flow sensor: current i [A] → flow q [l/min].

Structure (paper 1 Sec. 3.3, Fig. 3; all states per run)::

    τ_i  i̇_c = i − i_c                         hardware current controller (PSV1010)
    i_m = play(i_c, hysteresis)                 magnetic hysteresis of the solenoid
    τ_p  ẋ_p = clip(i_m / i_max, 0, 1) − x_p    pilot spool (normalised stroke)
    x_t = (x_p − p_th) / (1 − p_th)             main-spool set-point from the inner-chamber pressure:
                                                 it opens only above p_th ≈ 50 % current (Remark 6)
    τ_m  ẋ_m = x_t − x_m − F                    main spool, end stops [0, 1]; friction F: sticks while
                                                 |x_t − x_m| ≤ F_s, then F = F_c sign(ẋ_m)
    G = K_m x_m + K_p x_p                       orifice conductance [(l/min)/√bar], q ∝ A(x_m)√Δp
    q = min(G G_d / √(G² + G_d²) · √p_s, q_pump)   in series with the return path G_d (V_1T open),
                                                 so Δp over the valve changes with the flow (Sec. 5.1)
    sensor: delay τ_d, turbine lag τ_s, reading g(q) = q²/q_lo below q_lo, noise, clip to [0, q_hi]

The sensor's ≈ 50 ms delay, its 1.2–20 l/min range, the 30 bar supply, the pump's 21.9 l/min,
i_max = 1.01 A and f_s = 4 kHz are paper 1's (Sec. 5, 5.4, 5.5). The rest are assumptions chosen so
that the static characteristic resembles paper 1's: the main flow starts at ≈ 0.53 A (its i_0),
rises by ≈ 125 l/min/A (the FFC's κ gives 80–150 l/min/A at 10–30 bar) and saturates at the
pump's flow; the nominal ultra-local gain ρ = (∂q/∂i)/τ_m at 5 l/min is ≈ 0.14 m³/(A s²), a
third of the γ = 0.4 m³/(A s²) paper 1 tuned (Sec. 5.3), so its campaign 1 → 5 → 1 l/min is
feasible with its k_p = 30 1/s. Below q_lo the turbine under-reads (its "nonlinear characteristics
resulting from the measurement principle", Sec. 5.4), monotonically, so 1 l/min stays trackable.
The spool friction is small because the amplifier's 160 Hz dither (Sec. 5) breaks most of the
stiction; with three times more, an MFC at paper 1's gains hunts in a stick-slip limit cycle.

Integration: ``i`` held over the sample, ``n_sub`` sub-steps of at most ``max_substep`` [s], each
first-order stage advanced exactly with its input held over the sub-step (:func:`decay`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from labrunner._ufunc import clip
from labrunner.brent import brent_root
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigConfig, RigInfo, Signal
from labrunner.rigs.schema import Param
from labrunner.rigs.sim import SimRig
from labrunner.rigs.sim._integrate import DelayLine, decay, play, substeps
from labrunner.rigs.sim._noise import NoiseStreams

LPM_PER_M3S = 60_000.0  # 1 m³/s = 60 000 l/min
_POS = {"lo": 0.0, "lo_open": True}


def flow(x_main: np.ndarray, x_pilot: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
    """True flow [l/min] through the valve and the return path for spool strokes in [0, 1]."""
    g = p["main_conductance"] * x_main + p["pilot_conductance"] * x_pilot
    gd = p["downstream_conductance"]
    q = g * gd / np.sqrt(g * g + gd * gd) * np.sqrt(p["supply_pressure"])
    return np.minimum(q, p["pump_flow"])


def static_flow(i: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
    """Steady-state flow [l/min] at current ``i`` [A], without hysteresis and friction."""
    x_p = np.clip(np.asarray(i, dtype=float) / p["i_max"], 0.0, 1.0)
    x_m = np.clip((x_p - p["pilot_threshold"]) / (1.0 - p["pilot_threshold"]), 0.0, 1.0)
    return flow(x_m, x_p, p)


def nominal_gain(p: Mapping[str, Any], q_op: float = 5.0) -> float:
    """ρ of the ultra-local model q̇ = f + ρ i (paper 1 eq. 13) at ``q_op`` [l/min]: (∂q/∂i)/τ_m [(l/min)/(A s)]."""
    q_top = float(static_flow(p["i_max"], p))
    q_op = min(q_op, 0.5 * q_top)
    i_op = brent_root(lambda i: float(static_flow(i, p)) - q_op, p["pilot_threshold"] * p["i_max"], p["i_max"])
    di = 1e-5 * p["i_max"]
    slope = float(static_flow(i_op + di, p) - static_flow(i_op - di, p)) / (2.0 * di)
    return slope / p["main_tau"]


class ValveTwin(SimRig):
    """Batched twin of a pilot-operated proportional valve; input ``i`` [A], output ``q`` [l/min]."""

    KIND = "valve"
    PARAMETERS = {
        "i_max": Param(1.01, "A", "largest coil current (paper 1 Sec. 5.3)", **_POS),
        "current_tau": Param(1.5e-3, "s", "lag of the hardware current controller (assumed)", lo=0.0),
        "hysteresis": Param(0.02, "A", "width of the solenoid's magnetic hysteresis (assumed)", lo=0.0),
        "pilot_tau": Param(3e-3, "s", "pilot spool time constant (assumed)", lo=0.0),
        "pilot_threshold": Param(
            0.5, "1", "current fraction where the main spool opens (paper 1 Remark 6)", lo=0.0, hi=0.95
        ),
        "main_tau": Param(0.015, "s", "main spool time constant (assumed)", **_POS),
        "main_static_friction": Param(
            0.006, "1", "main spool breakaway, fraction of stroke, with dither (assumed)", lo=0.0, hi=0.5
        ),
        "main_coulomb_friction": Param(
            0.004, "1", "main spool sliding friction, fraction of stroke (assumed)", lo=0.0, hi=0.5
        ),
        "main_conductance": Param(12.0, "(l/min)/sqrt(bar)", "main orifice fully open (assumed)", **_POS),
        "pilot_conductance": Param(0.02, "(l/min)/sqrt(bar)", "pilot orifice fully open (assumed)", lo=0.0),
        "downstream_conductance": Param(
            6.0, "(l/min)/sqrt(bar)", "return path: chamber and open V_1T (assumed)", **_POS
        ),
        "supply_pressure": Param(30.0, "bar", "pump pressure (paper 1 Sec. 5.5)", **_POS),
        "pump_flow": Param(21.9, "l/min", "largest pump flow (paper 1 Sec. 5)", **_POS),
        "sensor_delay": Param(0.05, "s", "flow sensor delay tau_qp (paper 1 Sec. 5.4)", lo=0.0, hi=1.0),
        "sensor_tau": Param(5e-3, "s", "turbine lag on top of the delay (assumed)", lo=0.0),
        "sensor_min": Param(1.2, "l/min", "lower end of the sensor's range (EVS 3104-A-0020, paper 1 Sec. 5)", lo=0.0),
        "sensor_max": Param(20.0, "l/min", "upper end of the sensor's range (paper 1 Sec. 5)", **_POS),
        "max_substep": Param(1.25e-4, "s", "longest integration sub-step", lo=1e-7, hi=0.01),
    }
    NOISE = {
        "flow_lpm": Param(0.03, "l/min", "std of white noise on the flow reading (assumed)", lo=0.0),
    }

    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        p = super().validate_parameters(raw, path)
        _check_valve(p, path)
        return p

    @classmethod
    def check_overrides(
        cls, config: RigConfig, overrides: Mapping[str, Any], batch: int, path: str = "overrides"
    ) -> dict[str, np.ndarray]:
        p = super().check_overrides(config, overrides, batch, path)
        _check_valve(p, path)
        return p

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        p = {**{k: v.default for k, v in cls.PARAMETERS.items()}, **parameters}
        rho = nominal_gain(p)
        return RigInfo(
            name=name,
            kind=cls.KIND,
            inputs=(Signal("i", "A", 0.0, p["i_max"]),),
            outputs=(Signal("q", "l/min", 0.0, p["sensor_max"]),),
            fs_range=(500.0, 20_000.0),
            fs_default=4000.0,
            safe_input=(0.0,),
            constants={
                "rho": rho,
                "rho_si": rho / LPM_PER_M3S,
                "i_open": p["pilot_threshold"] * p["i_max"],
                "q_sensor_min": p["sensor_min"],
                "q_sensor_max": p["sensor_max"],
                "supply_pressure": p["supply_pressure"],
                "sensor_delay": p["sensor_delay"],
            },
            simulated=True,
            description=description or "simulated pilot-operated proportional valve with flow sensor (paper 1)",
        )

    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        p = self.per_run(batch, overrides)
        self.p = p
        self.n_sub = substeps(self.fs, float(p["max_substep"].min()))
        h = 1.0 / (self.fs * self.n_sub)
        self._e_i, self._e_p, self._e_m = decay(p["current_tau"], h), decay(p["pilot_tau"], h), decay(p["main_tau"], h)
        self._e_s = decay(p["sensor_tau"], 1.0 / self.fs)
        self._inv_open = 1.0 / (1.0 - p["pilot_threshold"])
        # constant over the runs, read every tick by :meth:`_read`
        self._noisy = bool(np.any(p["flow_lpm"] > 0.0))
        self._lo_or_1 = np.where(p["sensor_min"] > 0.0, p["sensor_min"], 1.0)
        self._i_c = np.zeros(batch)  # coil current [A]
        self._i_m = np.zeros(batch)  # magnetising current behind the hysteresis [A]
        self._x_p = np.zeros(batch)  # pilot stroke [1]
        self._x_m = np.zeros(batch)  # main stroke [1]
        self._moving = np.zeros(batch, dtype=bool)
        self._q = np.zeros(batch)  # true flow [l/min]
        self._delay = DelayLine(np.rint(p["sensor_delay"] * self.fs), fill=0.0)
        self._q_sensor = np.zeros(batch)  # turbine state [l/min]
        self._noise = NoiseStreams(seeds, 1, stream=2)
        return self._read()[:, None]

    def _step(self, u: np.ndarray) -> np.ndarray:
        p = self.p
        i = u[:, 0]
        width = p["hysteresis"]
        th, fs_, fc = p["pilot_threshold"], p["main_static_friction"], p["main_coulomb_friction"]
        i_c, i_m, x_p, x_m, moving = self._i_c, self._i_m, self._x_p, self._x_m, self._moving
        for _ in range(self.n_sub):
            i_c = i + (i_c - i) * self._e_i
            i_m = play(i_m, i_c, width)  # magnetic hysteresis
            target = clip(i_m / p["i_max"], 0.0, 1.0)
            x_p = target + (x_p - target) * self._e_p
            x_t = (x_p - th) * self._inv_open  # < 0: the spring preload holds the main spool shut
            e = x_t - x_m
            moving = np.abs(e) > np.where(moving, fc, fs_)
            x_eq = x_t - fc * np.sign(e)
            x_m = clip(np.where(moving, x_eq + (x_m - x_eq) * self._e_m, x_m), 0.0, 1.0)
        self._i_c, self._i_m, self._x_p, self._x_m, self._moving = i_c, i_m, x_p, x_m, moving
        self._q = flow(x_m, x_p, p)
        delayed = self._delay.push(self._q)
        self._q_sensor = delayed + (self._q_sensor - delayed) * self._e_s
        return self._read()[:, None]

    def _read(self) -> np.ndarray:
        """Flow reading [l/min]: turbine under-reading below its range, noise, clipped to [0, sensor_max]."""
        p, q = self.p, self._q_sensor
        reading = np.where(q < p["sensor_min"], q * q / self._lo_or_1, q)
        if self._noisy:
            reading = reading + p["flow_lpm"] * self._noise.next()[:, 0]
        return clip(reading, 0.0, p["sensor_max"])

    @property
    def state(self) -> dict[str, np.ndarray]:
        """True state per run: coil current [A], pilot and main stroke [1], true flow [l/min]."""
        return {
            "current": self._i_c.copy(),
            "pilot": self._x_p.copy(),
            "main": self._x_m.copy(),
            "flow": self._q.copy(),
        }


def _check_valve(p: Mapping[str, Any], path: str) -> None:
    """Cross-parameter rules: sliding ≤ breakaway friction; sensor range lo < hi."""
    if np.any(np.asarray(p["main_coulomb_friction"]) > np.asarray(p["main_static_friction"])):
        raise InvalidParameter(f"{path}.main_coulomb_friction", "must be <= main_static_friction")
    if np.any(np.asarray(p["sensor_min"]) >= np.asarray(p["sensor_max"])):
        raise InvalidParameter(f"{path}.sensor_min", "must be < sensor_max")
