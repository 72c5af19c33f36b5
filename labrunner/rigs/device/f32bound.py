"""An a-priori bound on what float32 arithmetic changes in a device's logged columns (pure).

Running error analysis (Wilkinson; Higham, *Accuracy and Stability of Numerical Algorithms*,
§3.3): every number of the law is a :class:`Bounded` — its float64 value and a bound on how far a
float32 implementation's value can be from it. Each operation propagates the bounds of its
operands through its condition (first order) and adds its own rounding, u = 2⁻²⁴ of its result
(IEEE 754 single precision, round to nearest: fl(a ∘ b) = (a ∘ b)(1 + δ), |δ| ≤ u); every
constant of the description is rounded once (u of its value). A dot product of L terms — a FIR
estimate — gets γ_L = Lu/(1 − Lu) of Σ|w_j x_j|, which holds in any summation order. The
:mod:`~labrunner.rigs.device.doclaw` law run on these numbers (``dtype=Bounded``) gives every
logged column's bound at every tick: docs/control-laws.md, "float32 devices", derives it law by
law and says what it assumes.
"""

from __future__ import annotations

import math
import operator
from collections import deque

import numpy as np

U = 2.0**-24  #: float32's unit roundoff


def gamma(n: int) -> float:
    """γ_n = nu / (1 − nu): the relative error bound of n roundings."""
    return n * U / (1.0 - n * U)


def _v(x) -> float:
    return x.v if isinstance(x, Bounded) else float(x)


def _e(x) -> float:
    return x.e if isinstance(x, Bounded) else 0.0  # a Python int or float operand is exact (small integers)


class Bounded:
    """A float64 value ``v`` and a bound ``e`` on a float32 computation's distance from it."""

    __slots__ = ("v", "e")

    def __init__(self, v, e: float | None = None) -> None:
        if isinstance(v, Bounded):
            self.v, self.e = v.v, v.e if e is None else e
        else:
            self.v = float(v)
            self.e = U * abs(self.v) if e is None else e  # a constant rounded to float32 once

    def __repr__(self) -> str:
        return f"Bounded({self.v!r} ± {self.e:.3g})"

    def _out(self, v: float, e: float) -> Bounded:
        return Bounded(v, e + U * abs(v))  # the operation's own rounding

    def __add__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        return self._out(self.v + _v(o), self.e + _e(o))

    __radd__ = __add__

    def __sub__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        return self._out(self.v - _v(o), self.e + _e(o))

    def __rsub__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        return self._out(_v(o) - self.v, self.e + _e(o))

    def __mul__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        a, b = self.v, _v(o)
        return self._out(a * b, abs(a) * _e(o) + abs(b) * self.e + self.e * _e(o))

    __rmul__ = __mul__

    def __truediv__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        return _div(self.v, self.e, _v(o), _e(o))

    def __rtruediv__(self, o) -> Bounded:
        if isinstance(o, np.ndarray):
            return NotImplemented  # numpy applies it element-wise
        return _div(_v(o), _e(o), self.v, self.e)

    def __pow__(self, n: int) -> Bounded:
        if n == 0:
            return Bounded(1.0, 0.0)
        v = self.v**n  # n − 1 multiplications
        return Bounded(v, n * abs(self.v) ** (n - 1) * self.e + gamma(n - 1) * abs(v))

    def __neg__(self) -> Bounded:
        return Bounded(-self.v, self.e)

    def __abs__(self) -> Bounded:
        return Bounded(abs(self.v), self.e)

    def sqrt(self) -> Bounded:
        if math.isnan(self.v) or math.isnan(self.e):  # a non-finite input's tick: no bound, and no comparison
            return Bounded(math.nan, math.nan)  # with NaN, whose invalid-operation flag numpy's np.sqrt would print
        v = math.sqrt(max(self.v, 0.0))
        low = max(self.v - self.e, 0.0)  # |√a' − √a| ≤ e / (√a + √(a − e)), or √(a + e) near 0
        e = self.e / (v + math.sqrt(low)) if low > 0 else math.sqrt(self.v + self.e)
        return Bounded(v, e + U * v)

    def sin(self) -> Bounded:  # |sin'| ≤ 1; a libm sinf within 1 ulp: 2u of 1 at most
        return Bounded(math.sin(self.v), self.e + 2 * U)

    def cos(self) -> Bounded:
        return Bounded(math.cos(self.v), self.e + 2 * U)

    def __lt__(self, o) -> bool:  # the float64 law's branch (docs: the bound assumes the same branch)
        return self.v < _v(o)

    def __le__(self, o) -> bool:
        return self.v <= _v(o)

    def __gt__(self, o) -> bool:
        return self.v > _v(o)

    def __ge__(self, o) -> bool:
        return self.v >= _v(o)

    def __float__(self) -> float:
        return self.v

    def __int__(self) -> int:
        return int(self.v)

    def __bool__(self) -> bool:
        return self.v != 0.0


def _div(a: float, ea: float, b: float, eb: float) -> Bounded:
    v = a / b
    return Bounded(v, (ea + abs(v) * eb) / abs(b) + U * abs(v))


def dot(w: np.ndarray, h: np.ndarray) -> Bounded:
    """Σ w_j h_j of L terms in any order: the operands' bounds through it, plus γ_L Σ|w_j h_j|."""
    wv, we = values(w), errors(w)
    hv, he = values(h), errors(h)
    terms = np.abs(wv * hv)
    e = float(np.sum(np.abs(wv) * he + np.abs(hv) * we + we * he) + gamma(len(wv) + 1) * np.sum(terms))
    return Bounded(float(np.dot(wv, hv)), e)


def clip(x: Bounded, lo: Bounded, hi: Bounded) -> Bounded:
    """min(max(x, lo), hi): clamping is 1-Lipschitz; a value clamped by more than its bound is clamped on the device too."""
    v = min(max(x.v, lo.v), hi.v)
    if x.v - x.e > hi.v:
        return Bounded(v, hi.e)
    if x.v + x.e < lo.v:
        return Bounded(v, lo.e)
    return Bounded(v, max(x.e, lo.e if v == lo.v else 0.0, hi.e if v == hi.v else 0.0))


_V, _E = operator.attrgetter("v"), operator.attrgetter("e")


def _field(a, get, plain) -> np.ndarray:
    """One field of every element of ``a`` as a float array of its shape. The law is run on arrays of
    :class:`Bounded` (the hot path: ``get`` reads them without a Python call per element); ``plain`` reads
    a mix of them and plain numbers, and a float array holds plain numbers only."""
    arr = np.asarray(a)
    if arr.dtype != object:
        return plain(arr)
    flat = arr.ravel()
    try:
        out = np.fromiter(map(get, flat), float, len(flat))
    except AttributeError:  # plain numbers among them
        out = np.fromiter(map(_v if get is _V else _e, flat), float, len(flat))
    return out.reshape(arr.shape)


def values(a) -> np.ndarray:
    """The float64 values of ``a`` (Bounded or plain numbers)."""
    return _field(a, _V, lambda arr: arr.astype(float))


def errors(a) -> np.ndarray:
    """The bounds of ``a`` (0 for a plain number: exact)."""
    return _field(a, _E, lambda arr: np.zeros(arr.shape))


class FilterBound:
    """One channel of a FILTER record, [out, x⁺] = [x, w] · M, in Bounded arithmetic. A linear
    recursion's rounding is bounded through its impulse response, not operation by operation
    (|A|ᵏ grows where a resonant A's powers decay): the state error that tick j's rounding η_j
    leaves at tick k is A^(k−1−j) η_j, so |e_out[k]| ≤ Σ_j |C A^(k−1−j)| η_j + |C Aᵏ| e_x0 + the
    output's own rounding. The state before tick 0, x0 = (I − A)⁻¹ B w0, is computed in float64
    and rounded once (docs/control-laws.md: (I − A) is ill-conditioned, so a device solves it in
    double precision).

    The sum keeps its first N terms, N the first power with q = ‖A^N‖∞ ≤ 1/2; the older ticks'
    share is at most T · max ‖η_j‖∞ per output, T = q R / (1 − q), R the first N terms' row sums
    of |C Aⁱ| (row(C A^(N+m)) = row(C A^m) A^N, so the tail is at most q times the whole sum):
    the cost per tick stays N, not k."""

    def __init__(self, M: np.ndarray, n: int, p: int, w0: np.ndarray) -> None:
        Mv = values(M)
        self.A, self.B = Mv[:n, p:].T, Mv[n:, p:].T
        self.C, self.D = Mv[:n, :p].T, Mv[n:, :p].T
        self.g = gamma(n + len(self.B.T) + 1)  # a sum of n + m products, M rounded once
        steady = np.linalg.solve(np.eye(n) - self.A, self.B) if n else np.zeros((0, len(self.B.T)))
        self.x = steady @ values(w0)
        self.e_x0 = U * np.abs(self.x) + np.abs(steady) @ errors(w0)
        self.power = self.C.copy()  # C A^k for the initial state's error at tick k
        self.apow = np.eye(n)  # A^i, i = len(kernel)
        self.kernel: list[np.ndarray] | np.ndarray = []  # |C A^i|, i = 0, 1, …, N − 1
        self.eta: deque[np.ndarray] = deque()  # the last ticks' local state errors, oldest first
        self.tail: np.ndarray | None = None  # T per output, once N is found
        self.dropped = 0.0  # the largest ‖η_j‖∞ of the ticks older than N

    def step(self, w: np.ndarray) -> np.ndarray:
        wv, we = values(w), errors(w)
        x = self.x
        out = self.C @ x + self.D @ wv
        e = self.g * (np.abs(self.C) @ np.abs(x) + np.abs(self.D) @ np.abs(wv)) + np.abs(self.D) @ we
        e = e + np.abs(self.power) @ self.e_x0
        if self.eta:
            e = e + np.einsum("ipn,in->p", np.array(self.kernel[: len(self.eta)]), np.array(self.eta)[::-1])
        if self.tail is not None:
            e = e + self.tail * self.dropped
        if self.tail is None:
            self.kernel.append(np.abs(self.power))  # type: ignore[union-attr]  # a list until N is found
            self.apow = self.apow @ self.A
            q = float(np.abs(self.apow).sum(axis=1).max(initial=0.0))
            if q <= 0.5:
                self.kernel = np.array(self.kernel)  # one array from now on
                self.tail = q * self.kernel.sum(axis=(0, 2)) / (1.0 - q)
                self.eta = deque(self.eta, maxlen=len(self.kernel))
        if self.eta.maxlen is not None and len(self.eta) == self.eta.maxlen:
            self.dropped = max(self.dropped, float(self.eta[0].max(initial=0.0)))
        self.eta.append(self.g * (np.abs(self.A) @ np.abs(x) + np.abs(self.B) @ np.abs(wv)) + np.abs(self.B) @ we)
        self.power = self.power @ self.A
        self.x = self.A @ x + self.B @ wv
        result = np.empty(len(out), object)
        result[:] = [Bounded(float(v), float(b) + U * abs(float(v))) for v, b in zip(out, e)]
        return result


def relu(x: Bounded) -> Bounded:
    """max(x, 0), 1-Lipschitz: 0 exactly where x is negative by more than its bound."""
    if x.v + x.e < 0:
        return Bounded(0.0, 0.0)
    return Bounded(max(x.v, 0.0), x.e)
