"""Numerics shared by the twins: sub-steps within one sample, exact ZOH discretisation, play, delay.

Every twin holds its input constant over a sample (zero-order hold) and advances its state in
``n`` equal sub-steps of ``h = 1/(n fs)`` so that switching effects (friction, backlash, end
stops) are resolved within the sample:

- linear parts: :func:`zoh_discretise` gives the exact transition ``x⁺ = Φ x + Γ w`` for a
  sub-step with ``w`` held (Van Loan: ``expm([[A, B], [0, 0]] h)``), per run (batched);
- first-order lags: :func:`decay` (``x⁺ = x_∞ + (x − x_∞)·e^(−h/τ)``, exact for a held target);
- backlash and hysteresis: :func:`play`; sensor dead time: :class:`DelayLine`.

All functions are pure and vectorised over a leading batch axis.
"""

from __future__ import annotations

import numpy as np


def substeps(fs: float, max_substep_s: float) -> int:
    """Number of equal sub-steps per sample so that each is at most ``max_substep_s`` [s] long."""
    return max(1, int(np.ceil((1.0 / fs) / max_substep_s - 1e-9)))


def zoh_discretise(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact discretisation of ``ẋ = A x + B w`` over ``h`` [s] with ``w`` held.

    ``A`` (..., n, n), ``B`` (..., n, m) → ``Φ = e^(A h)`` (..., n, n), ``Γ = ∫₀ʰ e^(A s) ds B``
    (..., n, m), from one matrix exponential of the augmented matrix (Van Loan 1978).
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n, m = A.shape[-1], B.shape[-1]
    M = np.zeros(A.shape[:-2] + (n + m, n + m))
    M[..., :n, :n] = A * h
    M[..., :n, n:] = B * h
    E = expm(M)
    return E[..., :n, :n], E[..., :n, n:]


_TAYLOR_TERMS = 20  #: ‖X‖₁ ≤ 1: the first omitted term is below 1/21! ≈ 2e-20 of ‖e^X‖


def expm(M: np.ndarray) -> np.ndarray:
    """e^M of each (…, k, k) matrix by scaling and squaring: a Taylor series of M/2^s, ‖M/2^s‖₁ ≤ 1,
    squared s times. The twins' sub-step matrices are small (‖M‖₁ ≲ 3), so s ≤ 3 and the result is
    within a few ulp of ``scipy.linalg.expm`` (tests/test_rigs_twins.py), whose import cost 0.18 s in
    every process that builds a motor twin (each campaign worker)."""
    M = np.asarray(M, dtype=float)
    norm = float(np.abs(M).sum(axis=-2).max(initial=0.0))
    s = max(0, int(np.ceil(np.log2(norm)))) if norm > 1.0 else 0
    X = M / 2.0**s
    E = term = np.broadcast_to(np.eye(M.shape[-1]), M.shape).copy()
    for k in range(1, _TAYLOR_TERMS + 1):
        term = term @ X / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def decay(tau: np.ndarray | float, h: float) -> np.ndarray:
    """``e^(−h/τ)`` per run; ``τ = 0`` (no lag) gives 0, i.e. the state jumps to its target."""
    tau = np.asarray(tau, dtype=float)
    with np.errstate(divide="ignore"):
        return np.where(tau > 0.0, np.exp(-h / np.where(tau > 0.0, tau, 1.0)), 0.0)


def play(y: np.ndarray, x: np.ndarray, width: np.ndarray | float) -> np.ndarray:
    """Play (backlash) operator: ``y`` follows ``x`` only once the gap ``width`` is taken up.

    The output stays put while ``|x − y| ≤ width/2`` and is dragged along otherwise; it models
    gearbox backlash and, as the elementary Prandtl operator, magnetic hysteresis.
    """
    half = 0.5 * np.asarray(width, dtype=float)
    return np.minimum(np.maximum(y, x - half), x + half)


class DelayLine:
    """A pure delay of ``delay`` samples per run (ring buffer (D_max + 1, B)); 0 means none."""

    def __init__(self, delay: np.ndarray, fill: np.ndarray) -> None:
        self.delay = np.asarray(delay, dtype=np.int64).reshape(-1)
        fill = np.broadcast_to(np.asarray(fill, dtype=float), self.delay.shape)
        self._buf = np.tile(fill, (int(self.delay.max(initial=0)) + 1, 1))
        self._cols = np.arange(self.delay.size)
        self._i = 0

    def push(self, x: np.ndarray) -> np.ndarray:
        """Store this sample's ``x`` (B,) and return the value from ``delay`` samples ago (B,)."""
        L = self._buf.shape[0]
        self._i = (self._i + 1) % L
        self._buf[self._i] = x
        return self._buf[(self._i - self.delay) % L, self._cols]
