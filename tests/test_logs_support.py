"""Synthetic runs for the log tests (until the engine exists): a motor-like velocity-MFC run.

Ω̇ = −aΩ + b·u with the thesis's a = 39.44 1/s, b = 108.55 rad/(V s²), a poly-5 set-point
transition 0 → 40 → 0 rad/s, the 11-bit encoder's quantisation of θ, f_s = 200 Hz.
"""

from __future__ import annotations

import numpy as np

A, B = 39.44, 108.55
CHANNELS = {
    "theta": {"role": "output", "unit": "rad"},
    "omega": {"role": "controlled", "unit": "rad/s"},
    "ref_omega": {"role": "reference", "unit": "rad/s"},
    "e_omega": {"role": "error", "unit": "rad/s"},
    "u": {"role": "input", "unit": "V"},
    "f_hat_omega": {"role": "estimate", "unit": "rad/s^2"},
}


def poly5(t: np.ndarray, t0: float, t1: float, y0: float, y1: float) -> np.ndarray:
    s = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return y0 + (y1 - y0) * s**3 * (10 - 15 * s + 6 * s**2)


def motor_run(fs: float = 200.0, duration: float = 5.0, seed: int = 0) -> dict[str, np.ndarray]:
    """Signals of a motor velocity run (explicit Euler, P-tracking with feed-forward, noise)."""
    rng = np.random.default_rng(seed)
    k_n = round(fs * duration)
    t = np.arange(k_n) / fs
    ref = poly5(t, 0.5, 1.5, 0.0, 40.0) - poly5(t, 2.5, 3.5, 0.0, 40.0)
    omega, theta, u = np.zeros(k_n), np.zeros(k_n), np.zeros(k_n)
    for k in range(k_n - 1):
        u[k] = np.clip((A * omega[k] + (ref[k + 1] - ref[k]) * fs - 50.0 * (omega[k] - ref[k])) / B, -12, 12)
        omega[k + 1] = omega[k] + (-A * omega[k] + B * u[k]) / fs + 0.05 * rng.standard_normal()
        theta[k + 1] = theta[k] + omega[k] / fs
    theta = np.round(theta / (2 * np.pi / 2048)) * (2 * np.pi / 2048)
    return {
        "theta": theta,
        "omega": omega,
        "ref_omega": ref,
        "e_omega": omega - ref,
        "u": u,
        "f_hat_omega": -A * omega + 0.3 * rng.standard_normal(k_n),
    }


def metadata(point_id: str = "p-0042") -> dict:
    return {
        "run": {"point_id": point_id, "campaign": "motor-demo", "seed": 3, "start_time": "2024-05-01T12:00:00Z"},
        "config": {
            "controller": {"kind": "mfc1", "gamma": 108.55, "k_p": 50.0},
            "differentiator": {"alpha": 9, "beta": 9, "omega_c": 200.0},
            "reference": {"kind": "poly5", "levels": [0.0, 40.0, 0.0]},
        },
    }


ABORTED = {
    "status": "aborted",
    "monitor": "du_dt",
    "time": 2.6,
    "value": 151.2,
    "threshold": 120.0,
    "message": "|du/dt| >= 120 V/s",
}
COMPLETED = {"status": "completed", "monitor": None, "time": None, "value": None, "threshold": None, "message": ""}
