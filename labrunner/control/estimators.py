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

The sums are products of tap vectors with the signal histories (a
:class:`~labrunner.differentiators.History`); the y taps carry one leading zero, which realises the
shift ε = t_s. Two layouts, same numbers to rounding:

- *shared*: a batch of at least ``SHARED_MIN_ROWS`` rows B·C sharing one design keeps the
  histories of y, e (none when only the measurement is filtered: then e = y) and v and takes one
  BLAS product per tap vector over its signal's block;
- *bank*: otherwise (small batches, batches mixing designs) the row blocks [e; …; e; y; v] (the
  error once per filter on it) carry per-row taps, zero-padded to a common length, and one einsum
  sums each row in order, so that padding changes nothing and a run gives the same numbers alone
  as in any such batch.

Either way the products write straight into the estimates: a tick is a handful of ufunc calls
on preallocated buffers.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from labrunner.differentiators import Differentiator, History
from labrunner.errors import InvalidParameter

#: B·C from which a batch sharing one design uses the BLAS products (BLAS sums the taps in another
#: order than the bank, so smaller batches, B = 1 above all, stay with the bank).
SHARED_MIN_ROWS = 32


class _Window(NamedTuple):
    """Where one tick at one window position of the history writes and what it multiplies."""

    y_to: np.ndarray  # y[k] goes here (the error rows too when e = y)
    e_to: np.ndarray | None  # e[k] = y[k] − y_r[k] goes here (None: e = y, nothing to write)
    copies: tuple[np.ndarray, ...]  # further rows that take e[k] (the bank's ê̇ row)
    v_to: np.ndarray  # the applied v[k−1] goes here
    products: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # (taps, history block, target) to multiply


class MFCEstimator:
    """f̂, ê (and ê̇ for order 2) of B runs × C channels, one tick at a time.

    ``designs``: one differentiator per run; ``order``: n of the ultra-local model (1 or 2);
    ``gamma``: the input gain γ per run (B,) or per run and channel (B, C) (for a gain that
    varies in time, such as paper 2's γ_i(y) = γ_{i,0}/y, pass v := γ(t)·i and γ = 1, since
    (24b) filters the product); ``filter_error``: per run (B,) or for all, filter the error
    (thesis (2.36)) or only the measurement (paper 2 eq. (25)). :meth:`reset` (which forms the
    tap vectors) comes before the first :meth:`step`.
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
        self._m = np.array(np.broadcast_to(m[:, None], (B, C)), dtype=float)
        self._not_m = 1.0 - self._m
        self.gamma = np.array(
            np.broadcast_to(np.reshape(gamma, (B, -1)) if np.ndim(gamma) else gamma, (B, C)), dtype=float
        )
        self._unit_gamma = bool(np.all(self.gamma == 1.0))
        for d in designs:  # every normalisation the taps divide by (the tap vectors: the first reset)
            for k in range(order + 1):
                d.check_weights(k)
        self._designs = designs
        # one buffer: f̂, ê^(0..n−1), then the products of y and v. The filters on e write straight
        # into ê^(k) (the filtered outputs when e = y: the reference terms come off in place), and
        # the estimates sit side by side in :attr:`block` for the logs.
        self._buf = np.zeros((order + 3, B, C))
        self.block = self._buf[: 1 + order]
        self.f_hat, self.e_hat = self._buf[0], self._buf[1]
        self.de_hat = self._buf[2] if order == 2 else np.zeros((B, C))
        self._e_block, self._out_y, self._out_v = self._buf[1 : 1 + order], self._buf[1 + order], self._buf[2 + order]
        self._tmp = np.zeros((B, C))
        self._tmp_e = np.zeros((order, B, C))
        self._shared = B * C >= SHARED_MIN_ROWS and all(d == designs[0] for d in designs)
        self._hist: History | None = None

    def _start(self) -> None:
        """Form the tap vectors and the histories, once: a controller built only to validate a
        campaign's points has checked its designs' weights (cached on the shared designs) but
        builds no histories."""
        order = self.order
        # tap vectors per run: y (shifted by ε), e (one per filter), v
        taps = [
            [np.concatenate([[0.0], d.weights(order)]), *(d.weights(k) for k in range(order)), d.weights(0)]
            for d in self._designs
        ]
        if self._shared:
            self._init_shared(taps[0])
        else:
            self._init_bank(taps)

    def _init_shared(self, taps: list[np.ndarray]) -> None:
        """Histories of y, e (unless e = y) and v; one BLAS product per tap vector."""
        B, C, n = self.batch, self.channels, self.order
        L = taps[-1].size  # the y taps are one longer (the leading zero)
        e_signal = 0 if self._mode == "output" else 1
        self._hist = History(L + 1, B * C, 3 - (e_signal == 0))
        self._fill_rows = [0, 2] if e_signal == 0 else [0, 1, 2]
        self._taps = taps
        targets = [o.reshape(-1) for o in (self._out_y, *self._e_block, self._out_v)]  # in the taps' order
        # per window position: where y, e (None: e = y), copies of e and v go; (taps, block, target) products
        self._views: list[_Window] = []
        for rows, blocks in zip(self._hist.rows, self._hist.blocks):
            ry, rv = rows[0].reshape(B, C), rows[-1].reshape(B, C)
            re = None if e_signal == 0 else rows[1].reshape(B, C)
            products = [(taps[0], blocks[0], targets[0])]
            products += [(taps[1 + k], blocks[e_signal][:L], targets[1 + k]) for k in range(n)]
            products.append((taps[-1], blocks[-1][:L], targets[-1]))
            self._views.append(_Window(ry, re, (), rv, products))

    def _init_bank(self, taps: list[list[np.ndarray]]) -> None:
        """Row blocks [e; …; e; y; v] with per-row taps, zero-padded: one einsum summing in order."""
        B, C, n = self.batch, self.channels, self.order
        L = max(t.size for row in taps for t in row)
        bank = np.zeros((n + 2, B, C, L))
        for b, (t_y, *t_e, t_v) in enumerate(taps):
            for block, t in enumerate((*t_e, t_y, t_v)):  # the order of the products in the buffer
                bank[block, b, :, : t.size] = t
        self._bank = np.ascontiguousarray(bank.reshape(-1, L).T)  # (L, rows), like the history block
        self._hist = History(L, bank.shape[0] * B * C)
        self._fill_rows = [1] * n + [0, 2]
        target = self._buf[1:].reshape(-1)
        self._views: list[_Window] = []
        output = self._mode == "output"  # e = y: y goes to the error blocks and its own in one copy
        for rows, blocks in zip(self._hist.rows, self._hist.blocks):
            x = rows[0].reshape(n + 2, B, C)
            y_to, e_to, copies = (x[: 1 + n], None, ()) if output else (x[n], x[0], tuple(x[1:n]))
            self._views.append(_Window(y_to, e_to, copies, x[-1], [(self._bank, blocks[0], target)]))

    def reset(self, y0: np.ndarray, r0: np.ndarray | float = 0.0, v0: np.ndarray | float = 0.0) -> None:
        """Pre-fill the histories as a stationary past: y ≡ y0, y_r ≡ r0 (filtered errors only;
        r0 = y0 gives the thesis's zero initial error profile), v ≡ v0 (each (B, C) or scalar)."""
        if self._hist is None:
            self._start()
        fill = np.empty((3, self.batch, self.channels))
        fill[0] = y0
        fill[1] = y0 - self._m * r0
        fill[2] = v0
        rows = fill.reshape(3, -1)[self._fill_rows]
        self._hist.fill(rows if self._shared else rows.reshape(-1))

    def step(self, y: np.ndarray, v_prev: np.ndarray, r: np.ndarray) -> None:
        """Advance by one tick and update :attr:`f_hat`, :attr:`e_hat`, :attr:`de_hat` (B, C).

        ``y`` y[k] (B, C), ``v_prev`` the applied v[k−1] (B, C), ``r`` (B, C, 4) the reference
        and its derivatives at tick k.
        """
        mode, tmp = self._mode, self._tmp
        window = self._views[self._hist.advance()]
        window.y_to[...] = y
        window.v_to[...] = v_prev
        if mode == "error":
            np.subtract(y, r[:, :, 0], out=window.e_to)
        elif mode == "mixed":
            np.multiply(self._m, r[:, :, 0], out=tmp)
            np.subtract(y, tmp, out=window.e_to)
        for row in window.copies:  # the bank's second error row (ê̇)
            row[...] = window.e_to
        if self._shared:
            for taps, block, target in window.products:
                np.dot(taps, block, out=target)
        else:
            taps, block, target = window.products[0]
            np.einsum("lb,lb->b", taps, block, out=target)
        if self._unit_gamma:  # 1·x is x: one ufunc fewer (paper 2's γ_v = 1)
            np.subtract(self._out_y, self._out_v, out=self.f_hat)
        else:
            np.multiply(self.gamma, self._out_v, out=tmp)
            np.subtract(self._out_y, tmp, out=self.f_hat)
        if mode != "error":  # (n, B, C) filtered outputs minus the reference's derivatives 0..n−1
            r_k = r.transpose(2, 0, 1)[: self.order]
            if mode == "mixed":
                r_k = np.multiply(self._not_m, r_k, out=self._tmp_e)
            np.subtract(self._e_block, r_k, out=self._e_block)
