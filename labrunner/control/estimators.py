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

The sums run through :class:`~labrunner.differentiators.StreamingFIR` over the stacked signal
rows [y; y − m·y_r; v] of the B·C channels (B runs, C outputs; m = 1 where the error is
filtered, 0 where the measurement is). The y taps carry one leading zero, which realises the
shift ε = t_s. Two layouts, same numbers: when every run shares one design and the batch is
large, one FIR per tap vector with the taps shared by all rows (a BLAS product per tick);
otherwise one FIR bank with per-row taps, zero-padded to a common length (one call per tick,
best for B = 1 and for batches mixing designs).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.differentiators import Differentiator, StreamingFIR, pad_taps
from labrunner.errors import InvalidParameter


SHARED_MIN_ROWS = 32  # B·C from which shared taps (one FIR per tap vector) beat one per-row bank


class MFCEstimator:
    """f̂, ê (and ê̇ for order 2) of B runs × C channels, one tick at a time.

    ``designs``: one differentiator per run; ``order``: n of the ultra-local model (1 or 2);
    ``gamma``: the input gain γ per run (B,) or per run and channel (B, C) (for a gain that
    varies in time, such as paper 2's γ_i(y) = γ_{i,0}/y, pass v := γ(t)·i and γ = 1, since
    (24b) filters the product); ``filter_error``: per run (B,) or for all, filter the error
    (thesis (2.36)) or only the measurement (paper 2 eq. (25)).
    """

    def __init__(
        self,
        designs: Sequence[Differentiator],
        order: int,
        gamma: np.ndarray | float = 1.0,
        channels: int = 1,
        *,
        filter_error: bool | np.ndarray = True,
    ):
        if order not in (1, 2):
            raise InvalidParameter("order", f"must be 1 or 2 (ultra-local model order), got {order!r}")
        self.order, self.channels = order, channels
        self.batch = B = len(designs)
        C = channels
        m = np.broadcast_to(np.asarray(filter_error, dtype=bool), (B,))
        self._mode = "error" if m.all() else "output" if not m.any() else "mixed"
        self._m = m.astype(float).reshape(B, 1)
        self._not_m = 1.0 - self._m
        self.gamma = np.array(np.broadcast_to(np.reshape(gamma, (B, -1)) if np.ndim(gamma) else gamma, (B, C)), dtype=float)
        # tap vectors per run: y rows (shifted by ε), e rows (one per filter), v rows
        taps = [
            [np.concatenate([[0.0], d.weights(order)]), *(d.weights(k) for k in range(order)), d.weights(0)]
            for d in designs
        ]
        self._x = np.zeros((3, B, C))
        self._flat = self._x.reshape(-1)
        self._flat_e = self._x[1].reshape(-1)
        self._shared = B * C >= SHARED_MIN_ROWS and all(d == designs[0] for d in designs)
        if self._shared:
            self._firs = [StreamingFIR(t) for t in taps[0]]  # y, e (order filters), v
        else:
            L = max(t.size for row in taps for t in row)
            bank = np.zeros((3, B, C, order, L))
            for b, row in enumerate(taps):
                bank[0, b, :, 0, : row[0].size] = row[0]
                for k in range(order):
                    bank[1, b, :, k, : row[1 + k].size] = row[1 + k]
                bank[2, b, :, 0, : row[-1].size] = row[-1]
            self._firs = [StreamingFIR(bank.reshape(3 * B * C, order, L))]
        self._tmp = np.zeros((B, C))
        self.f_hat = np.zeros((B, C))
        self.e_hat = np.zeros((B, C))
        self.de_hat = np.zeros((B, C))

    def reset(self, y0: np.ndarray, r0: np.ndarray | float = 0.0, v0: np.ndarray | float = 0.0) -> None:
        """Pre-fill the histories as a stationary past: y ≡ y0, y_r ≡ r0 (filtered errors only;
        r0 = y0 gives the thesis's zero initial error profile), v ≡ v0 (each (B, C) or scalar)."""
        fill = np.empty((3, self.batch, self.channels))
        fill[0] = y0
        fill[1] = y0 - self._m * r0
        fill[2] = v0
        if self._shared:
            rows = self.batch * self.channels
            for fir, i in zip(self._firs, [0] + [1] * self.order + [2]):
                fir.reset(rows, fill[i].reshape(-1))
        else:
            self._firs[0].reset(self._flat.size, fill.reshape(-1))

    def step(self, y: np.ndarray, v_prev: np.ndarray, r: np.ndarray) -> None:
        """Advance by one tick and update :attr:`f_hat`, :attr:`e_hat`, :attr:`de_hat` (B, C).

        ``y`` y[k] (B, C), ``v_prev`` the applied v[k−1] (B, C), ``r`` (B, C, 4) the reference
        and its derivatives at tick k. Few, allocation-light ufunc calls: this runs every tick.
        """
        x, tmp, mode = self._x, self._tmp, self._mode
        shape = (self.batch, self.channels)
        if mode == "error":
            np.subtract(y, r[:, :, 0], out=x[1])
        elif mode == "output":
            x[1] = y
        else:
            np.multiply(self._m, r[:, :, 0], out=tmp)
            np.subtract(y, tmp, out=x[1])
        if self._shared:  # push y, e and v straight into their FIRs
            f = self._firs
            out_y = f[0].step(np.reshape(y, -1)).reshape(shape)
            out_e = [fir.step(self._flat_e).reshape(shape) for fir in f[1:-1]]
            out_v = f[-1].step(np.reshape(v_prev, -1)).reshape(shape)
        else:
            x[0] = y
            x[2] = v_prev
            out = self._firs[0].step(self._flat).reshape(3, *shape, self.order)
            out_y, out_e, out_v = out[0, :, :, 0], [out[1, :, :, k] for k in range(self.order)], out[2, :, :, 0]
        np.multiply(self.gamma, out_v, out=tmp)
        np.subtract(out_y, tmp, out=self.f_hat)
        for k, (o, est) in enumerate(zip(out_e, (self.e_hat, self.de_hat))):
            if mode == "error":
                est[...] = o
            elif mode == "output":
                np.subtract(o, r[:, :, k], out=est)
            else:
                np.multiply(self._not_m, r[:, :, k], out=tmp)
                np.subtract(o, tmp, out=est)
