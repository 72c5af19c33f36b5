"""Linear filters of the plate controllers (paper 2 Sec. 4.2, Fig. 10), designed continuous and
discretised by Tustin's method with prewarping, then run as batched state-space systems.

- :func:`notch_tf`: the notch of Tietze & Schenk Sec. 13.8 at the plate's resonance (942 rad/s),
  used by the MBC and the MFC on the measurement (Fig. 10a and 10b);
- :func:`lowpass_tf`: Butterworth low-pass filters (the MBC's slope matching);
- :func:`tustin`: bilinear transform prewarped at a frequency, where the discrete response equals
  the continuous one exactly (Oppenheim & Schafer Sec. 5.1.3);
- :func:`series`, :func:`parallel`: connections of discrete systems;
- :class:`StreamingSS`: B runs × C channels of one discrete system each, one tick at a time.

The three designs are written out here in numpy (Butterworth's poles, the controllable canonical
form, the bilinear transform) rather than taken from ``scipy.signal``, whose import (~0.4 s) was
most of a plate campaign's start-up; tests/test_plate_filters.py checks them against it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

StateSpace = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # (A, B, C, D)


def notch_tf(omega: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Notch (s² + ω_0²) / (s² + (ω_0/Q) s + ω_0²): zero gain at ω_0 [rad/s], −3 dB width ω_0/Q."""
    return np.array([1.0, 0.0, omega**2]), np.array([1.0, omega / q, omega**2])


def lowpass_tf(order: int, omega: float) -> tuple[np.ndarray, np.ndarray]:
    """Butterworth low-pass of ``order`` with cutoff ``omega`` [rad/s]; order 0 is 1."""
    if order == 0:
        return np.array([1.0]), np.array([1.0])
    m = np.arange(1 - order, order, 2)
    poles = -omega * np.exp(1j * np.pi * m / (2 * order))  # left half of the circle of radius ω
    return np.array([omega**order]), np.poly(poles).real


def tf_ss(num: np.ndarray, den: np.ndarray) -> StateSpace:
    """State space of a SISO transfer function (a static gain has no states)."""
    if len(den) == 1:
        return np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.array([[num[0] / den[0]]])
    n = len(den) - 1  # controllable canonical form of num/den, proper (len(num) <= len(den))
    num = np.concatenate([np.zeros(n + 1 - len(num)), num]) / den[0]
    den = np.asarray(den, dtype=float) / den[0]
    A = np.vstack([-den[1:], np.eye(n - 1, n)])
    B = np.eye(n, 1)
    C = (num[1:] - num[0] * den[1:]).reshape(1, n)
    return A, B, C, np.array([[num[0]]])


def identity(n: int = 1) -> StateSpace:
    """The static system y = w with ``n`` channels."""
    return np.zeros((0, 0)), np.zeros((0, n)), np.zeros((n, 0)), np.eye(n)


def tustin(ss: StateSpace, fs: float, omega_warp: float) -> StateSpace:
    """Tustin discretisation at ``fs`` [Hz] prewarped at ``omega_warp`` [rad/s]; static systems pass."""
    if len(ss[0]) == 0:
        return ss
    dt = 2.0 * np.tan(omega_warp / (2.0 * fs)) / omega_warp  # s = (2/dt)(z − 1)/(z + 1) is exact at omega_warp
    A, B, C, D = ss
    eye = np.eye(len(A))
    back = eye - 0.5 * dt * A  # x[k+1] − x[k] = dt·(A (x[k+1] + x[k])/2 + B w)
    Ad = np.linalg.solve(back, eye + 0.5 * dt * A)
    Bd = np.linalg.solve(back, dt * B)
    Cd = np.linalg.solve(back.T, C.T).T
    return Ad, Bd, Cd, D + 0.5 * C @ Bd


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """Discrete systems in series: ``second`` driven by ``first``'s outputs."""
    A1, B1, C1, D1 = first
    A2, B2, C2, D2 = second
    n1, n2 = len(A1), len(A2)
    A = np.block([[A1, np.zeros((n1, n2))], [B2 @ C1, A2]])
    return A, np.vstack([B1, B2 @ D1]), np.hstack([D2 @ C1, C2]), D2 @ D1


def parallel(systems: Sequence[StateSpace]) -> StateSpace:
    """Block-diagonal stack: the inputs of system j feed only its outputs."""
    return tuple(_block_diag([s[i] for s in systems]) for i in range(4))  # type: ignore[return-value]


def _block_diag(mats: Sequence[np.ndarray]) -> np.ndarray:
    out = np.zeros((sum(m.shape[0] for m in mats), sum(m.shape[1] for m in mats)))
    r = c = 0
    for m in mats:
        out[r : r + m.shape[0], c : c + m.shape[1]] = m
        r, c = r + m.shape[0], c + m.shape[1]
    return out


def frequency_response(ss: StateSpace, omega: np.ndarray, fs: float | None = None) -> np.ndarray:
    """Response (len(ω), n_out, n_in) of a continuous (``fs`` None) or discrete system at ω [rad/s]."""
    A, B, C, D = ss
    w = np.asarray(omega, dtype=float)
    points = 1j * w if fs is None else np.exp(1j * w / fs)
    if len(A) == 0:
        return np.broadcast_to(D.astype(complex), (len(w),) + D.shape).copy()
    eye = np.eye(len(A))
    return np.array([C @ np.linalg.solve(p * eye - A, B) + D for p in points])


class StreamingSS:
    """B runs × C channels of discrete systems x⁺ = A x + B w, out = C x + D w; one system per run.

    ``systems`` holds one (A, B, C, D) per run (same numbers of inputs and outputs; state sizes
    are zero-padded to the largest). Each tick is one product [x, w] @ [[Cᵀ, Aᵀ], [Dᵀ, Bᵀ]]: a single
    2-d product when every run has the same system, else a batched one.
    """

    def __init__(self, systems: Sequence[StateSpace], channels: int) -> None:
        self.n = max(len(s[0]) for s in systems)
        self.m, self.p = systems[0][1].shape[1], systems[0][2].shape[0]
        n, m, p = self.n, self.m, self.p
        B = len(systems)
        self._M = np.zeros((B, n + m, p + n))
        self._steady = np.zeros((B, n, m))  # x = (I − A)⁻¹ B w for a constant w
        for b, (A, Bm, C, D) in enumerate(systems):
            k = len(A)
            self._M[b, :k, :p], self._M[b, n:, :p] = C.T, D.T
            self._M[b, :k, p : p + k], self._M[b, n:, p : p + k] = A.T, Bm.T
            if k:
                self._steady[b, :k] = np.linalg.solve(np.eye(k) - A, Bm)
        self._z = np.zeros((B, channels, n + m))  # [x[k], w[k]] per run and channel
        self._out = np.zeros((B, channels, p + n))  # [out[k], x[k+1]]
        self._shared = self._M[0] if np.all(self._M == self._M[0]) else None
        self._flat, self._out_flat = self._z.reshape(B * channels, n + m), self._out.reshape(B * channels, p + n)
        self._state, self._input = self._z[:, :, :n], self._z[:, :, n:]
        self._output, self._next = self._out[:, :, :p], self._out[:, :, p:]

    def reset(self, w0: np.ndarray) -> None:
        """Start in the steady state of a constant input ``w0`` (B, C, m)."""
        self._z[...] = 0.0
        self._state[...] = np.einsum("bnj,bcj->bcn", self._steady, np.asarray(w0, dtype=float))

    @property
    def input(self) -> np.ndarray:
        """(B, C, m) where w[k] goes before :meth:`advance` (what :meth:`step` copies ``w`` to)."""
        return self._input

    @property
    def output(self) -> np.ndarray:
        """(B, C, p) where :meth:`advance` leaves out[k] (the array it returns)."""
        return self._output

    def step(self, w: np.ndarray) -> np.ndarray:
        """Feed w[k] (B, C, m); return out[k] (B, C, p), a view the next step overwrites, and advance the state."""
        self._input[...] = w
        return self.advance()

    def advance(self) -> np.ndarray:
        """:meth:`step` with w[k] already written to :attr:`input`."""
        if self._shared is not None:
            np.dot(self._flat, self._shared, out=self._out_flat)
        else:
            np.matmul(self._z, self._M, out=self._out)
        self._state[...] = self._next
        return self._output
