"""Streaming estimates for model-free control: the unknown part f̂ and the filtered error ê, ê̇.

Generalised estimate of the unknown part of the ultra-local model y⁽ⁿ⁾ = f + γ v (thesis (2.20)
for n = 1, (2.25) for n = 2; paper 2 eq. (24b)), discretised as in thesis (3.4) and paper 2
eq. (25) with ε = t_s::

    f̂[k] = Σ_j ŵ_n[j] y[k−1−j] − γ Σ_j ŵ_0[j] v[k−1−j]

with ŵ_n = (1/Φ_n) w_n the normalised weights of the n-th derivative of the algebraic
differentiator (newest sample first). The error is filtered by the same differentiator
(thesis (2.36) and (2.49))::

    ê[k] = Σ_j ŵ_0[j] e[k−j],   ê̇[k] = Σ_j ŵ_1[j] e[k−j],

or, for runs with ``filter_error`` false (paper 2 eq. (25): only the measurement is filtered),
ê[k] = ŷ[k] − y_r[k] and ê̇[k] = ŷ̇[k] − ẏ_r[k].

All three sums run through one :class:`~labrunner.differentiators.StreamingFIR` over a stacked
signal: rows [y; y − m·y_r; v] of the B·C channels (B runs, C outputs; m = 1 where the error is
filtered, 0 where the measurement is), each row with its own taps;
the y rows' taps carry one leading zero, which realises the shift ε = t_s. Runs with different
differentiator designs are zero-padded to a common length.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.differentiators import Differentiator, StreamingFIR, pad_taps
from labrunner.errors import InvalidParameter


class MFCEstimator:
    """f̂, ê (and ê̇ for order 2) of B runs × C channels, one tick at a time.

    ``designs``: one differentiator per run; ``order``: n of the ultra-local model (1 or 2);
    ``filter_error``: per run (B,) or for all, filter the error (thesis) or the measurement (paper 2).
    """

    def __init__(
        self,
        designs: Sequence[Differentiator],
        order: int,
        channels: int = 1,
        *,
        filter_error: bool | np.ndarray = True,
    ):
        if order not in (1, 2):
            raise InvalidParameter("order", f"must be 1 or 2 (ultra-local model order), got {order!r}")
        self.order, self.channels = order, channels
        self.batch = len(designs)
        B, C = self.batch, channels
        self._m = np.broadcast_to(np.asarray(filter_error, dtype=float), (B,)).reshape(B, 1).copy()
        self._not_m = 1.0 - self._m
        n_filters = order  # e rows: ŵ_0 (and ŵ_1); y rows: shifted ŵ_n; v rows: ŵ_0
        w0 = pad_taps([d.weights(0) for d in designs])  # (B, L)
        wn = pad_taps([np.concatenate([[0.0], d.weights(order)]) for d in designs])  # shift by ε = t_s
        rows_e = [w0] + ([pad_taps([d.weights(1) for d in designs])] if order == 2 else [])
        L = max(w0.shape[1], wn.shape[1], *(w.shape[1] for w in rows_e))
        taps = np.zeros((3, B, C, n_filters, L))
        taps[0, :, :, 0, : wn.shape[1]] = wn[:, None, :]
        for m, w in enumerate(rows_e):
            taps[1, :, :, m, : w.shape[1]] = w[:, None, :]
        taps[2, :, :, 0, : w0.shape[1]] = w0[:, None, :]
        self._fir = StreamingFIR(taps.reshape(3 * B * C, n_filters, L))
        self._x = np.zeros((3, B, C))
        self._tmp = np.zeros((B, C))
        self.f_hat = np.zeros((B, C))
        self.e_hat = np.zeros((B, C))
        self.de_hat = np.zeros((B, C))

    def reset(self, y0: np.ndarray, r0: np.ndarray | float = 0.0, v0: np.ndarray | float = 0.0) -> None:
        """Pre-fill the histories as a stationary past: y ≡ y0, y_r ≡ r0 (filtered errors only;
        0: the thesis's zero initial error profile), v ≡ v0 (each (B, C) or scalar)."""
        fill = np.empty((3, self.batch, self.channels))
        fill[0] = y0
        fill[1] = y0 - self._m * r0
        fill[2] = v0
        self._fir.reset(3 * self.batch * self.channels, fill.reshape(-1))

    def step(self, y: np.ndarray, v_prev: np.ndarray, gamma: np.ndarray, r: np.ndarray) -> None:
        """Advance by one tick and update :attr:`f_hat`, :attr:`e_hat`, :attr:`de_hat` (B, C).

        ``y`` y[k] (B, C), ``v_prev`` the applied v[k−1] (B, C), ``gamma`` (B, 1) or (B, C),
        ``r`` (B, C, 4) the reference and its derivatives at tick k.
        """
        x, tmp = self._x, self._tmp
        x[0] = y
        np.multiply(self._m, r[:, :, 0], out=tmp)
        np.subtract(y, tmp, out=x[1])
        x[2] = v_prev
        out = self._fir.step(x.reshape(-1)).reshape(3, self.batch, self.channels, self.order)
        np.multiply(gamma, out[2, :, :, 0], out=self.f_hat)
        np.subtract(out[0, :, :, 0], self.f_hat, out=self.f_hat)
        np.multiply(self._not_m, r[:, :, 0], out=tmp)
        np.subtract(out[1, :, :, 0], tmp, out=self.e_hat)
        if self.order == 2:
            np.multiply(self._not_m, r[:, :, 1], out=tmp)
            np.subtract(out[1, :, :, 1], tmp, out=self.de_hat)
