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

With Coulomb friction (``friction=True``, ``identify --friction``) the model is
θ̈ = −a θ̇ + b (u − u_c sign θ̇), i.e. θ̈ = (u, −θ̇, −sign θ̇)·(b, a, b u_c)ᵀ, sign θ̇ filtered by
the order-0 kernel like u. Within one step from rest sign θ̇ is a scaled copy of u, so u_c is only
identifiable across step heights: the friction fit pools the runs into one least-squares problem.
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


@dataclass(frozen=True)
class FrictionEstimate:
    """a [1/s], b [rad/(V s²)] and the Coulomb voltage u_c [V] of one pooled fit over several runs."""

    a: float
    b: float
    coulomb: float
    n_samples: int
    residual_rms: float  # [rad/s²]


def filtered_signals(theta: np.ndarray, u: np.ndarray, fs: float, **design: float) -> tuple[np.ndarray, ...]:
    """(û, θ̇̂, θ̈̂, ŝ) at t = (k + 1/2)/fs − δ_t from samples θ[k] and held inputs u[k] (thesis 3.1).

    ŝ is sign θ̇ filtered like u: the sign of θ[k] − θ[k−1] belongs to the mid-point of that
    sample interval, as the mean of the held inputs does. Samples before the window is full (the
    first n_s) are dropped.
    """
    d = differentiators.design(fs=fs, **{**THESIS_DESIGN, **design})
    u_mid = np.concatenate([[u[0]], 0.5 * (u[1:] + u[:-1])])
    s_mid = np.concatenate([[0.0], np.sign(np.diff(theta))])
    g0 = d.weights(0)
    u_hat, s_hat = lfilter(g0, 1.0, u_mid), lfilter(g0, 1.0, s_mid)
    dtheta = lfilter(d.weights(1), 1.0, theta)
    ddtheta = lfilter(d.weights(2), 1.0, theta)
    keep = slice(d.n_s, None)
    return u_hat[keep], dtheta[keep], ddtheta[keep], s_hat[keep]


def _checked(theta: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    theta = np.asarray(theta, dtype=float)
    u = np.asarray(u, dtype=float)
    if theta.shape != u.shape or theta.ndim != 1:
        raise InvalidParameter("signals", f"theta and u must be 1-D of equal length, got {theta.shape} and {u.shape}")
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(u))):
        raise InvalidParameter("signals", "theta and u must be finite")
    return theta, u


#: Smallest singular value of G with unit columns below which a regressor is taken as a copy of
#: the others (one step alone: ≈ 0.005 for sign θ̇ against u; two step heights: ≈ 0.04).
MIN_SINGULAR = 0.015


def _solve(G: np.ndarray, y: np.ndarray, what: str) -> tuple[np.ndarray, float]:
    """Least-squares p̂ = (GᵀG)⁻¹Gᵀy (3.2) and the RMS of its residual; G must be well conditioned."""
    norms = np.linalg.norm(G, axis=0)
    if np.any(norms == 0.0) or np.linalg.svd(G / norms, compute_uv=False)[-1] < MIN_SINGULAR:
        raise InvalidParameter("signals", what)
    p, *_ = np.linalg.lstsq(G, y, rcond=None)
    return p, float(np.sqrt(np.mean((G @ p - y) ** 2)))


def identify_signals(theta: np.ndarray, u: np.ndarray, fs: float, **design: float) -> Estimate:
    """Least-squares a and b of θ̈ = −a θ̇ + b u from one experiment (thesis 3.2).

    ``theta``: measured angle [rad] at t = k/fs; ``u``: applied input [V] held over each sample.
    ``design`` overrides the differentiator of the thesis (alpha, beta, omega_c, N, method).
    """
    theta, u = _checked(theta, u)
    u_hat, dtheta, ddtheta, _ = filtered_signals(theta, u, fs, **design)
    if u_hat.size < 2:
        raise InvalidParameter("signals", f"need more than the differentiator window of samples, got {theta.size}")
    (b, a), residual = _solve(
        np.column_stack([u_hat, -dtheta]), ddtheta, "input and velocity are not independent (no step in the input?)"
    )
    return Estimate(float(a), float(b), int(u_hat.size), residual)


def identify_friction(runs: Sequence[tuple[np.ndarray, np.ndarray]], fs: float, **design: float) -> FrictionEstimate:
    """a, b and the Coulomb voltage u_c of θ̈ = −a θ̇ + b (u − u_c sign θ̇), pooled over ``runs``
    ((θ, u) pairs as for :func:`identify_signals`): one least-squares problem over all their samples.
    """
    rows = []
    for theta, u in runs:
        theta, u = _checked(theta, u)
        rows.append(np.column_stack(filtered_signals(theta, u, fs, **design)))
    if not rows:
        raise InvalidParameter("logs", "need at least one run")
    X = np.vstack(rows)
    u_hat, dtheta, ddtheta, s_hat = X.T
    (b, a, c), residual = _solve(
        np.column_stack([u_hat, -dtheta, -s_hat]),
        ddtheta,
        "input, velocity and sign of the velocity are not independent: "
        "the friction fit needs steps of at least two heights",
    )
    return FrictionEstimate(float(a), float(b), float(c / b), int(X.shape[0]), residual)


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
    friction: bool = False,
) -> dict[str, object]:
    """Identify a and b from each run log and average them (thesis Sec. 3.2).

    The angle is the rig measurement ``output_name`` (default: the first whose name starts with
    "theta"), the input ``input_name`` (default: the rig's first input). With ``nominal`` (the
    rig's a and b), the result also gives the relative bias (â − a)/a, (b̂ − b)/b — what friction,
    backlash and quantisation do to the estimate. With ``friction``, ``result["friction"]`` holds
    the pooled fit with a Coulomb term (:func:`identify_friction`).
    """
    from labrunner.logs import read_run

    if not paths:
        raise InvalidParameter("logs", "need at least one run log")
    per_run, signals = [], []
    fs = None
    for path in paths:
        log = read_run(path)
        frame = log.frame
        roles = {name: info.get("role") for name, info in log.channels.items()}
        u_name = _pick([n for n, r in roles.items() if r == "input"], input_name, "input", "u")
        y_name = _pick([n for n, r in roles.items() if r == "output"], output_name, "output", "theta")
        theta, level = frame[y_name].to_numpy(), frame[u_name].to_numpy()
        if fs is not None and float(log.fs) != fs:
            raise InvalidParameter("logs", f"all runs need one sampling rate, got {fs:g} and {float(log.fs):g} Hz")
        fs = float(log.fs)
        est = identify_signals(theta, level, fs)
        signals.append((theta, level))
        per_run.append(
            {
                "log": str(path),
                "input": u_name,
                "output": y_name,
                "u_final": float(level[-1]),
                "torn": bool(log.torn),
                **asdict(est),
            }
        )
    result: dict[str, object] = {
        "a": float(np.mean([r["a"] for r in per_run])),
        "b": float(np.mean([r["b"] for r in per_run])),
        "a_std": float(np.std([r["a"] for r in per_run])),
        "b_std": float(np.std([r["b"] for r in per_run])),
        "design": THESIS_DESIGN,
        "per_run": per_run,
    }
    if friction:
        result["friction"] = asdict(identify_friction(signals, fs))
    if nominal:
        result["nominal"] = {k: float(nominal[k]) for k in ("a", "b") if k in nominal}
        result["bias"] = {k: result[k] / v - 1.0 for k, v in result["nominal"].items()}
    return result


def _rig_of(path: str | Path, search: Sequence[str | Path] | None) -> tuple[dict[str, float], dict[str, object]] | None:
    """(constants, parameters) of the rig a log was recorded on, the run's ``rig_parameters``
    overrides applied, or None when the rig file cannot be found."""
    from labrunner.logs import read_metadata
    from labrunner.rigs import config as rigconfig

    meta = read_metadata(path)
    rig = meta.get("run", {}).get("rig")
    if not isinstance(rig, str):
        return None
    try:
        config = rigconfig.load_rig_config(rig, search)
        constants = dict(rigconfig.rig_info(config).constants)
    except (InvalidParameter, OSError):
        return None
    overrides = meta.get("config", {}).get("rig_parameters") or {}
    constants.update({k: float(overrides[f"identified_{k}"]) for k in ("a", "b") if f"identified_{k}" in overrides})
    return constants, {**config.parameters, **overrides}


def nominal_constants(path: str | Path, search: Sequence[str | Path] | None = None) -> dict[str, float] | None:
    """The nominal a and b of the rig a log was recorded on (rig constants: on the motor twin the
    values thesis Sec. 3.2 identified, with the run's ``rig_parameters`` overrides), or None when
    the rig file cannot be found (``search``: rig directories, default the registry's)."""
    rig = _rig_of(path, search)
    found = {k: float(rig[0][k]) for k in ("a", "b") if k in rig[0]} if rig else {}
    return found or None


def physical_parameters(path: str | Path, search: Sequence[str | Path] | None = None) -> dict[str, float] | None:
    """The motor twin's physical a, b and Coulomb voltage (``coulomb``) a log was recorded with,
    what :func:`identify_friction` estimates; None for a rig without them (a real motor)."""
    rig = _rig_of(path, search)
    keys = {"a": "a", "b": "b", "coulomb": "coulomb_friction"}
    if rig is None or not all(isinstance(rig[1].get(v), (int, float)) for v in keys.values()):
        return None
    return {k: float(rig[1][v]) for k, v in keys.items()}
