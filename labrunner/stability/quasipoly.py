"""Quasi-polynomials Δ(s) = Σ_k P_k(s)·exp(−s·τ_k): the characteristic functions of linear
delay differential equations with constant delays (thesis appendix A, the form Δ*(s)).

A scalar n-th order equation Σ_k Σ_i c_{k,i}·y⁽ⁱ⁾(t − τ_k) = 0 has the characteristic function
Δ(s) = Σ_k (Σ_i c_{k,i} sⁱ)·exp(−s τ_k). It is *retarded* when only the undelayed term (τ_0 = 0)
carries sⁿ and *neutral* when a delayed term does too (thesis (A.11)).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter, check_finite


@dataclass(frozen=True, eq=False)
class QuasiPolynomial:
    """Δ(s) = Σ_k P_k(s)·exp(−s·delays[k]).

    ``coeffs[k]`` holds P_k's coefficients, highest power first (``numpy.polyval`` order), all rows
    of length n + 1 (n = degree ≥ 1); ``delays[0] == 0`` and the other delays are distinct and > 0
    [s]. ``coeffs[0, 0]`` (the undelayed sⁿ coefficient) must be non-zero.
    """

    coeffs: np.ndarray
    delays: np.ndarray

    def __post_init__(self) -> None:
        c = np.atleast_2d(np.asarray(self.coeffs, dtype=float))
        d = np.atleast_1d(np.asarray(self.delays, dtype=float))
        if c.shape[0] != d.shape[0] or c.shape[1] < 2:
            raise InvalidParameter("coeffs", f"must be (K, n+1) with n >= 1 and K = len(delays), got {c.shape}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(d))):
            raise InvalidParameter("coeffs", "coefficients and delays must be finite")
        if d[0] != 0.0 or np.any(d[1:] <= 0.0) or len(np.unique(d)) != len(d):
            raise InvalidParameter("delays", f"must start with 0 and be distinct and > 0 after it, got {d.tolist()}")
        if c[0, 0] == 0.0:
            raise InvalidParameter("coeffs", "the undelayed highest-order coefficient must be non-zero")
        object.__setattr__(self, "coeffs", c)
        object.__setattr__(self, "delays", d)

    @classmethod
    def from_terms(cls, terms: Mapping[float, Sequence[float]]) -> QuasiPolynomial:
        """Build from ``{delay_s: [coefficients, highest power first]}``; rows are left-padded
        with zeros to a common degree. ``{0: [1, a], d: [c]}`` is s + a + c·exp(−s d)."""
        items = sorted((check_finite("delay", k), np.atleast_1d(np.asarray(v, dtype=float))) for k, v in terms.items())
        if not items or items[0][0] != 0.0:
            items.insert(0, (0.0, np.zeros(1)))
        width = max(len(v) for _, v in items)
        coeffs = np.zeros((len(items), width))
        for row, (_, v) in enumerate(items):
            coeffs[row, width - len(v) :] = v
        return cls(coeffs, np.array([k for k, _ in items]))

    @property
    def degree(self) -> int:
        return self.coeffs.shape[1] - 1

    @property
    def tau_max(self) -> float:
        return float(self.delays[-1])

    @property
    def neutral_terms(self) -> np.ndarray:
        """Normalised delayed sⁿ coefficients b_k = c_{k,n}/c_{0,n} for k ≥ 1 (all zero if retarded)."""
        return self.coeffs[1:, 0] / self.coeffs[0, 0]

    @property
    def is_neutral(self) -> bool:
        return bool(np.any(self.neutral_terms != 0.0))

    def scaled(self) -> QuasiPolynomial:
        """The same roots in normalised time t/τ_max: Δ̃(σ) = τ_maxⁿ·Δ(σ/τ_max), delays in units
        of τ_max (the largest is 1). Keeps the collocation well conditioned for any delay."""
        tau = self.tau_max
        if tau == 0.0:
            return self
        powers = tau ** np.arange(self.degree + 1)  # column j multiplies s^(n−j)
        return QuasiPolynomial(self.coeffs * powers, self.delays / tau)

    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Δ(s), Δ'(s) and Σ_k |P_k(s) e^{−sτ_k}| (the size of the terms, for residual tests)."""
        s = np.asarray(s, dtype=complex)
        n = self.degree
        vander = s[..., None] ** np.arange(n, -1, -1)  # (..., n+1)
        dcoeffs = self.coeffs[:, :-1] * np.arange(n, 0, -1)  # P_k' coefficients
        p = vander @ self.coeffs.T  # (..., K)
        dp = vander[..., 1:] @ dcoeffs.T
        e = np.exp(-s[..., None] * self.delays)
        terms = p * e
        return terms.sum(-1), ((dp - self.delays * p) * e).sum(-1), np.abs(terms).sum(-1)
