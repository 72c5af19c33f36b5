"""Frequency responses of algebraic differentiators and the discretisation cost J_n.

Continuous: F(ω) = (jω)ⁿ·G(jω), G the Fourier transform of the kernel (2.2) (Kiltz 2017; Othmane
et al. 2022, Sec. 4.2). Discrete: F_d(ω) = Σ_j w[j]·e^{−jω(j+θ)t_s} with the normalised weights of
(2.4) and θ the quadrature's sample offset, so both refer to the same continuous time.
J_n = ∫₀^Ω |F_d − F|² dω / ∫₀^Ω |F|² dω (Kiltz 2017, Sec. 3.4.2; Othmane et al. 2022, Sec. 4.3).
"""

from __future__ import annotations

import math

import numpy as np

from labrunner.differentiators.design import Differentiator
from labrunner.differentiators.kernel import log_rho
from labrunner.errors import InvalidParameter

_CHUNK = 2_000_000  # nodes × frequencies evaluated at once (memory bound of ~32 MB)
COST_MAX_WORK = 10_000_000  # taps × frequencies of one cost J_n (≈ 2 s; it grows with both)


def _as_omega(omega: np.ndarray) -> np.ndarray:
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    if not np.all(np.isfinite(w)):
        raise InvalidParameter("omega", "must be finite frequencies [rad/s]")
    return w


def continuous_response(d: Differentiator, order: int, omega: np.ndarray) -> np.ndarray:
    """F(ω) = (jω)ⁿ G(jω) of the continuous differentiator at ω [rad/s] (complex, shape of ω).

    G(jω) = ∫₀^T g(τ) e^{−jωτ} dτ is evaluated by Gauss–Jacobi quadrature for the weight
    (1−ν)^α(1+ν)^β, which is exact for the polynomial part of g; the node count resolves
    e^{−jωτ} up to the largest |ω| (error near machine precision).
    """
    from scipy import special  # here, not at import: the engine and the campaign checks need no spectra

    n = d.check_order(order)
    w = _as_omega(omega)
    T = d.window_s
    z = float(np.max(np.abs(w))) * T / 2.0
    nodes = math.ceil((d.N + z + 10.0 * z ** (1.0 / 3.0) + 40.0) / 2.0)
    nu, weight = special.roots_jacobi(nodes, d.alpha, d.beta)
    weight = weight / weight.sum()  # ρ₀·B(α+1, β+1) = 1: G(0) = 1
    lr0 = log_rho(d.alpha, d.beta, 0)
    poly = np.zeros_like(nu)
    for i in range(d.N + 1):
        c = special.eval_jacobi(i, d.alpha, d.beta, d.theta) * math.exp(log_rho(d.alpha, d.beta, i) - lr0)
        poly += c * special.eval_jacobi(i, d.alpha, d.beta, nu)
    tau = T * (1.0 - nu) / 2.0
    vec = weight * poly
    g = np.empty(w.shape, dtype=complex)
    step = max(1, _CHUNK // nodes)
    for start in range(0, w.size, step):
        ws = w[start : start + step]
        g[start : start + step] = np.exp(-1j * np.outer(ws, tau)) @ vec
    return (1j * w) ** n * g


def discrete_response(d: Differentiator, order: int, omega: np.ndarray) -> np.ndarray:
    """F_d(ω) = Σ_j w[j] e^{−jω(j+θ)t_s} of the discretised differentiator at ω [rad/s] (complex)."""
    taps = d.weights(order)
    w = _as_omega(omega)
    times = (np.arange(taps.size) + d.sample_offset) / d.fs
    out = np.empty(w.shape, dtype=complex)
    step = max(1, _CHUNK // taps.size)
    for start in range(0, w.size, step):
        out[start : start + step] = np.exp(-1j * np.outer(w[start : start + step], times)) @ taps
    return out


def amplitude_phase(response: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude |F| and unwrapped phase arg F [rad] of a frequency response."""
    return np.abs(response), np.unwrap(np.angle(response))


def cost_db(d: Differentiator, order: int, omega_max: float | None = None, points: int = 1000) -> float:
    """Discretisation cost J_n in dB, 20·log10(J_n), over ``points`` frequencies in [0, Ω].

    Ω defaults to the Nyquist frequency π·f_s. The 20·log10 scale is the one of paper 2, Table 1
    (J_2 < −200 dB acceptable) and AlgDiff's examples; J_n itself is a ratio of energies.
    """
    if d.n_s * int(points) > COST_MAX_WORK:
        raise InvalidParameter(
            "cost",
            f"needs n_s × points <= {COST_MAX_WORK:,}, got {d.n_s} taps × {int(points)} frequencies; "
            "use a shorter window (or a higher omega_c) or a lower fs",
        )
    omega = np.linspace(0.0, math.pi * d.fs if omega_max is None else float(omega_max), int(points))
    f = continuous_response(d, order, omega)
    fd = discrete_response(d, order, omega)
    from scipy import integrate  # here, not at import: only the offline design tools need it

    j = integrate.trapezoid(np.abs(fd - f) ** 2, omega) / integrate.trapezoid(np.abs(f) ** 2, omega)
    return 20.0 * math.log10(j) if j > 0.0 else -math.inf
