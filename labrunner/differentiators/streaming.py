"""Causal FIR evaluation of differentiators: one sample per tick for a batch, or a whole signal.

Both evaluate thesis (2.4) without extra delay: the output at sample k is Σ_j w[j]·x[k−j] with w
newest sample first, so it estimates x⁽ⁿ⁾(k·t_s − Differentiator.discrete_delay_s(n)).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.differentiators.design import Differentiator
from labrunner.errors import InvalidParameter


def pad_taps(taps: Sequence[np.ndarray]) -> np.ndarray:
    """Stack 1-D tap vectors (newest sample first) into (B, L), zero-padding the oldest end."""
    if len(taps) == 0:
        raise InvalidParameter("taps", "must hold at least one tap vector, got none")
    rows = [np.asarray(t, dtype=float) for t in taps]
    if any(r.ndim != 1 or r.size == 0 for r in rows):
        raise InvalidParameter("taps", "must be non-empty 1-D arrays")
    out = np.zeros((len(rows), max(r.size for r in rows)))
    for i, r in enumerate(rows):
        out[i, : r.size] = r
    return out


class History:
    """The last ``length`` samples of ``signals`` signals of ``width`` channels, newest first.

    A sliding window over a buffer of ``length + spare`` rows per signal: a tick writes one row
    and moves no data; every ``spare`` ticks the newest ``length − 1`` rows are copied back to
    the end of the buffer at once. So each signal's last ``length`` samples are always one
    contiguous (length, width) block, as BLAS wants it. The views of every window position are
    made once, so a tick costs a list lookup, not a slice.
    """

    def __init__(self, length: int, width: int, signals: int = 1) -> None:
        if length < 1 or width < 1 or signals < 1:
            raise InvalidParameter(
                "length", f"length, width and signals must be >= 1, got {length}, {width}, {signals}"
            )
        self.length, self.width, self.signals = length, width, signals
        self._spare = max(length, 64)  # ticks between two copies; a copy of length − 1 rows each time
        self._buf = np.zeros((signals, self._spare + length, width))
        #: per window position: the rows to write the newest sample to, and the blocks, per signal
        self.rows = [tuple(self._buf[:, pos]) for pos in range(self._spare + 1)]
        self.blocks = [tuple(self._buf[:, pos : pos + length]) for pos in range(self._spare + 1)]
        self.pos = self._spare

    def fill(self, value: float | np.ndarray) -> None:
        """A constant past: every stored sample of signal s equals ``value[s]`` (broadcast to (signals, width))."""
        self._buf[...] = np.broadcast_to(value, (self.signals, self.width))[:, None, :]
        self.pos = self._spare

    def advance(self) -> int:
        """Open the next window position and return it; write the newest samples to ``rows[pos]``."""
        pos = self.pos
        if pos == 0:
            n = self.length - 1
            self._buf[:, self._spare + 1 :] = self._buf[:, :n]
            pos = self._spare + 1
        self.pos = pos = pos - 1
        return pos


class StreamingFIR:
    """A bank of causal FIR filters over one history buffer, advanced one sample per tick.

    ``taps`` is (L,) (one filter for every run), (B, L) (one per run) or (B, M, L) (M filters per
    run, e.g. derivatives 0..M−1); newest sample first. The history is a :class:`History`.
    """

    def __init__(self, taps: np.ndarray) -> None:
        t = np.asarray(taps, dtype=float)
        if t.ndim not in (1, 2, 3) or t.shape[-1] == 0 or not np.all(np.isfinite(t)):
            raise InvalidParameter("taps", f"must be finite with shape (L,), (B, L) or (B, M, L), got shape {t.shape}")
        self._length = t.shape[-1]
        self._runs = None if t.ndim == 1 else t.shape[0]
        self._out_ndim = 1 if t.ndim == 3 else 0  # outputs (B, M) from (B, M, L), else (B,)
        # Runs that all share one filter bank use one matrix product (BLAS) instead of einsum.
        self._shared = t.ndim == 1 or bool(np.all(t == t[:1]))
        if self._shared:
            self._taps = np.ascontiguousarray(t if t.ndim == 1 else t[0])  # (L,) or (M, L)
        else:  # (B, L) as (L, B); (B, M, L) as (M, L, B): contiguous like the history block
            self._taps = np.ascontiguousarray(np.transpose(t, (1, 0) if t.ndim == 2 else (1, 2, 0)))
        self.reset(self._runs or 1)

    @property
    def length(self) -> int:
        """Number of taps L (history length in samples)."""
        return self._length

    def reset(self, batch: int, fill: float | np.ndarray = 0.0) -> None:
        """Start ``batch`` runs with a history of L samples equal to ``fill`` (scalar or (B,)).

        Filling with the first measurement gives a steady start: a constant history.
        """
        if isinstance(batch, bool) or int(batch) != batch or batch < 1:
            raise InvalidParameter("batch", f"must be an integer >= 1, got {batch!r}")
        if self._runs is not None and batch != self._runs:
            raise InvalidParameter("batch", f"must equal the {self._runs} runs of the taps, got {batch}")
        fill_arr = np.asarray(fill, dtype=float)
        if fill_arr.ndim > 1 or (fill_arr.ndim == 1 and fill_arr.size != batch):
            raise InvalidParameter("fill", f"must be a scalar or have shape ({batch},), got shape {fill_arr.shape}")
        if getattr(self, "_history", None) is None or self._history.width != batch:
            self._history = History(self._length, int(batch))
        self._history.fill(fill_arr)

    def step(self, x: np.ndarray, out: np.ndarray | None = None, filter_major: bool = False) -> np.ndarray:
        """Push the newest sample x (B,) and return the filter outputs (B,) or (B, M), in ``out`` if given.

        ``filter_major``: outputs (M, B) instead of (B, M), each filter's outputs contiguous.
        """
        h = self._history
        pos = h.advance()
        h.rows[pos][0][...] = x
        block = h.blocks[pos][0]  # (L, B), newest first
        if out is None:
            shape = (block.shape[1], self._taps.shape[0]) if self._out_ndim else (block.shape[1],)
            out = np.empty(shape[::-1] if filter_major else shape)
        if self._shared:
            if self._out_ndim == 0:
                return np.dot(self._taps, block, out=out)
            # One matrix-vector product per filter: OpenBLAS is several times slower on an (M, L)
            # by (L, B) product with small M than on M products (L,) by (L, B).
            for m, row in enumerate(self._taps):
                if filter_major:
                    np.dot(row, block, out=out[m])
                else:
                    out[:, m] = np.dot(row, block)
            return out
        if self._out_ndim == 0:
            return np.einsum("lb,lb->b", self._taps, block, out=out)
        return np.einsum("mlb,lb->mb" if filter_major else "mlb,lb->bm", self._taps, block, out=out)


def estimate(design: Differentiator, x: np.ndarray, order: int) -> np.ndarray:
    """Offline estimate of the ``order``-th derivative of whole signals x (..., K), time last.

    y[..., k] = Σ_j w[j]·x[..., k−j] with x[..., k−j] = x[..., 0] for k−j < 0 (the steady start of
    :meth:`StreamingFIR.reset` with ``fill = x[0]``), so y equals the streaming output sample by
    sample and y[k] ≈ x⁽ⁿ⁾(k·t_s − design.discrete_delay_s(order)); no delay is added beyond that.
    """
    w = design.weights(order)
    xs = np.asarray(x, dtype=float)
    if xs.ndim == 0 or xs.shape[-1] == 0:
        raise InvalidParameter("x", f"must have a non-empty time axis (last), got shape {xs.shape}")
    head = np.repeat(xs[..., :1], w.size - 1, axis=-1)
    padded = np.concatenate([head, xs], axis=-1)
    kernel = w.reshape((1,) * (xs.ndim - 1) + (w.size,))
    from scipy import signal  # here, not at import: the engine's streaming path does not need it

    return signal.oaconvolve(padded, kernel, mode="valid", axes=-1)
