"""Least-squares identification of the DC motor's a and b from logged experiments (thesis Sec. 3.2).

Model (2.31): θ̈ = −a θ̇ + b u, i.e. θ̈ = (u, −θ̇)·(b, a)ᵀ. The derivatives θ̇, θ̈ are estimated
by algebraic differentiators (N = 0, α = β = 6, ω_c = 50 rad/s, mid-point rule) and u is filtered
by the same kernel of order 0, so that all three carry the same delay δ_t (3.1). Stacking the K
estimates gives G p = y, solved by least squares, p̂ = (GᵀG)⁻¹Gᵀy (3.2); the thesis takes the
mean of p̂ over its four step experiments (−12, −6, +6, +12 V at 100 Hz).

Timing: the mid-point estimate from θ[k−j] belongs to t = (k + 1/2)·t_s. The input is held
(zero-order hold) over [k, k+1)·t_s, so the mid-point of the kernel's j-th interval straddles
u[k−j−1] and u[k−j]; their mean is the mid-point value. Without this half-sample alignment the
estimates of a and b are biased by about 17 % at 100 Hz.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from labrunner import differentiators
from labrunner.errors import InvalidParameter

#: Differentiator of thesis Sec. 3.2.
THESIS_DESIGN = {"alpha": 6.0, "beta": 6.0, "omega_c": 50.0, "N": 0, "method": "midpoint"}


@dataclass(frozen=True)
class Estimate:
    """Identified parameters of one experiment: a [1/s], b [rad/(V s²)], samples used, fit residual."""

    a: float
    b: float
    n_samples: int
    residual_rms: float  # RMS of G p̂ − y [rad/s²]


def filtered_signals(theta: np.ndarray, u: np.ndarray, fs: float, **design: float) -> tuple[np.ndarray, ...]:
    """(û, θ̇̂, θ̈̂) at t = (k + 1/2)/fs − δ_t from samples θ[k] and held inputs u[k] (thesis 3.1).

    Samples before the window is full (the first n_s) are dropped.
    """
    d = differentiators.design(fs=fs, **{**THESIS_DESIGN, **design})
    u_mid = np.concatenate([[u[0]], 0.5 * (u[1:] + u[:-1])])
    u_hat = lfilter(d.weights(0), 1.0, u_mid)
    dtheta = lfilter(d.weights(1), 1.0, theta)
    ddtheta = lfilter(d.weights(2), 1.0, theta)
    keep = slice(d.n_s, None)
    return u_hat[keep], dtheta[keep], ddtheta[keep]


def identify_signals(theta: np.ndarray, u: np.ndarray, fs: float, **design: float) -> Estimate:
    """Least-squares a and b of θ̈ = −a θ̇ + b u from one experiment (thesis 3.2).

    ``theta``: measured angle [rad] at t = k/fs; ``u``: applied input [V] held over each sample.
    ``design`` overrides the differentiator of the thesis (alpha, beta, omega_c, N, method).
    """
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    if theta.shape != u.shape or theta.ndim != 1:
        raise InvalidParameter("signals", f"theta and u must be 1-D of equal length, got {theta.shape} and {u.shape}")
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(u))):
        raise InvalidParameter("signals", "theta and u must be finite")
    u_hat, dtheta, ddtheta = filtered_signals(theta, u, fs, **design)
    if u_hat.size < 2:
        raise InvalidParameter("signals", f"need more than the differentiator window of samples, got {theta.size}")
    G = np.column_stack([u_hat, -dtheta])
    if np.linalg.matrix_rank(G) < 2:
        raise InvalidParameter("signals", "input and velocity are not independent (no step in the input?)")
    (b, a), *_ = np.linalg.lstsq(G, ddtheta, rcond=None)
    residual = G @ np.array([b, a]) - ddtheta
    return Estimate(float(a), float(b), int(u_hat.size), float(np.sqrt(np.mean(residual**2))))


def _pick(names: Sequence[str], wanted: str | None, field: str, prefer: str) -> str:
    if wanted is not None:
        if wanted not in names:
            raise InvalidParameter(field, f"must be one of {sorted(names)}, got {wanted!r}")
        return wanted
    if not names:
        raise InvalidParameter(field, "the log has no such channel")
    return next((n for n in names if n.startswith(prefer)), names[0])


def identify_logs(
    paths: Sequence[str | Path],
    *,
    input_name: str | None = None,
    output_name: str | None = None,
    nominal: dict[str, float] | None = None,
) -> dict[str, object]:
    """Identify a and b from each run log and average them (thesis Sec. 3.2).

    The angle is the rig measurement ``output_name`` (default: the first whose name starts with
    "theta"), the input ``input_name`` (default: the rig's first input). With ``nominal`` (the
    rig's a and b), the result also gives the relative bias (â − a)/a, (b̂ − b)/b — what friction,
    backlash and quantisation do to the estimate.
    """
    from labrunner.logs import read_run

    if not paths:
        raise InvalidParameter("logs", "need at least one run log")
    per_run = []
    for path in paths:
        log = read_run(path)
        frame = log.frame
        roles = {name: info.get("role") for name, info in log.channels.items()}
        u_name = _pick([n for n, r in roles.items() if r == "input"], input_name, "input", "u")
        y_name = _pick([n for n, r in roles.items() if r == "output"], output_name, "output", "theta")
        est = identify_signals(frame[y_name].to_numpy(), frame[u_name].to_numpy(), float(log.fs))
        level = frame[u_name].to_numpy()
        per_run.append({"log": str(path), "input": u_name, "output": y_name,
                        "u_final": float(level[-1]), "torn": bool(log.torn), **asdict(est)})
    result: dict[str, object] = {
        "a": float(np.mean([r["a"] for r in per_run])),
        "b": float(np.mean([r["b"] for r in per_run])),
        "a_std": float(np.std([r["a"] for r in per_run])),
        "b_std": float(np.std([r["b"] for r in per_run])),
        "design": THESIS_DESIGN,
        "per_run": per_run,
    }
    if nominal:
        result["nominal"] = {k: float(nominal[k]) for k in ("a", "b") if k in nominal}
        result["bias"] = {k: result[k] / v - 1.0 for k, v in result["nominal"].items()}
    return result


def nominal_constants(path: str | Path, search: Sequence[str | Path] | None = None) -> dict[str, float] | None:
    """The nominal a and b of the rig a log was recorded on (rig file constants, with the run's
    ``rig_parameters`` overrides), or None when the rig file cannot be found (``search``: rig
    directories, default the registry's)."""
    from labrunner.logs import read_metadata
    from labrunner.rigs import config as rigconfig

    meta = read_metadata(path)
    rig = meta.get("run", {}).get("rig")
    if not isinstance(rig, str):
        return None
    try:
        constants = dict(rigconfig.rig_info(rigconfig.load_rig_config(rig, search)).constants)
    except (InvalidParameter, OSError):
        return None
    overrides = meta.get("config", {}).get("rig_parameters") or {}
    constants.update({k: float(v) for k, v in overrides.items() if k in ("a", "b")})
    found = {k: float(constants[k]) for k in ("a", "b") if k in constants}
    return found or None
