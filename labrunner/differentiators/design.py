"""Design and discretisation of algebraic differentiators (thesis Sec. 2.1, (2.1)-(2.4)).

``design`` turns (α, β, N, ϑ, ω_c or T, f_s) into a :class:`Differentiator` whose window is a
whole number of samples n_s (carried as an int, never re-derived from a float), and whose
``weights(order)`` are the normalised FIR coefficients (1/Φ_n)·w_n of thesis (2.4), newest sample
first: x̂⁽ⁿ⁾[k + θ] = Σ_j weights[j]·x[k − j].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from labrunner.differentiators.kernel import default_theta, kernel_u, log_cutoff_product
from labrunner.errors import InvalidParameter, check_finite, check_positive

METHODS = ("midpoint", "trapezoidal", "analytic")
MAX_SAMPLES = 2**24  # longest window [samples]; guards against windows that cannot be held in memory
MAX_N = 20  # highest truncation order N: the kernel costs O(N·n_s) and its Jacobi terms lose float64 accuracy beyond
MAX_EXPONENT = 200.0  # largest α, β: the window (∝ √(αβ)/ω_c) and the kernel's dynamic range grow with them
_INTEGER_TOL = 1e-6  # a window within this many samples of an integer is that integer (float rounding)


@dataclass(frozen=True)
class Differentiator:
    """A discretised algebraic differentiator; build it with :func:`design`.

    ``theta`` is ϑ of (2.2); for N = 0 it holds the equivalent (β−α)/(α+β+2) so that
    δ_t = (1−ϑ)T/2 for every N. ``window_s`` = n_s/fs [s], ``delay_s`` = δ_t of (2.3) [s],
    ``omega_c_actual`` the cutoff of the realised window [rad/s].
    """

    alpha: float
    beta: float
    N: int
    theta: float
    fs: float
    n_s: int
    method: str
    window_s: float
    delay_s: float
    omega_c_actual: float
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def ts(self) -> float:
        """Sampling period t_s = 1/f_s [s]."""
        return 1.0 / self.fs

    @property
    def max_order(self) -> int:
        """Highest derivative order n with n < min(α, β) + 1 (thesis Sec. 2.1)."""
        return math.ceil(min(self.alpha, self.beta) + 1.0) - 1

    @property
    def sample_offset(self) -> float:
        """θ of (2.4) in samples: the estimate from x[k], x[k−1], ... belongs to time (k + θ)·t_s."""
        return 0.0 if self.method == "trapezoidal" else 0.5

    def check_order(self, order: int) -> int:
        """Return ``order`` or raise :class:`InvalidParameter` if this design cannot estimate it."""
        if isinstance(order, bool) or not check_finite("order", order, "an integer >= 0").is_integer() or order < 0:
            raise InvalidParameter("order", f"must be an integer >= 0, got {order!r}")
        order = int(order)
        for name, value in (("alpha", self.alpha), ("beta", self.beta)):
            if not value > order - 1:
                raise InvalidParameter(name, f"must be > n - 1 = {order - 1} for derivative order {order}, got {value}")
        return order

    def check_weights(self, order: int) -> int:
        """Return ``order`` or raise :class:`InvalidParameter` where :meth:`weights` would refuse it.

        Forms the weights (cached) where their normalisation Φ_n could vanish — a window of a few
        samples, or an under-resolved kernel, can sample g⁽ⁿ⁾ where its terms cancel — so that
        validating a campaign refuses such a design before anything runs. Not for n = 0 and N = 0,
        whose Φ_0 is a sum of positive terms: reading a delay forms nothing.
        """
        n = self._refuse(order)
        if n or self.N:
            self.weights(n)
        return n

    def _refuse(self, order: int) -> int:
        """``order``, checked against α, β and the discretisation (no kernel evaluated)."""
        n = self.check_order(order)
        if self.method == "trapezoidal" and min(self.alpha, self.beta) < n:
            raise InvalidParameter(
                "method",
                f"trapezoidal samples the window ends, where g^({n}) is infinite; needs "
                f"min(alpha, beta) >= {n} (or use midpoint/analytic), got {min(self.alpha, self.beta)}",
            )
        return n

    def kernel(self, order: int, tau: np.ndarray) -> np.ndarray:
        """Continuous kernel derivative g⁽ⁿ⁾(τ) of (2.2) at τ [s] (0 outside [0, T]) [1/s^{n+1}]."""
        n = self.check_order(order)
        T = self.window_s
        return kernel_u(self.alpha, self.beta, self.N, self.theta, n, np.asarray(tau) / T) / T ** (n + 1)

    def discrete_delay_s(self, order: int = 0) -> float:
        """Delay of the discrete estimate relative to the newest sample's time [s].

        x̂⁽ⁿ⁾[k] ≈ x⁽ⁿ⁾(k·t_s − discrete_delay_s): δ_t − θ·t_s with θ = 1/2 for mid-point and analytic,
        θ = 0 for trapezoidal (Othmane et al. 2022, Sec. 4.3). The same for every order.
        """
        self.check_order(order)
        return self.delay_s - self.sample_offset / self.fs

    def weights(self, order: int) -> np.ndarray:
        """Normalised coefficients (1/Φ_n)·w_n[j] of (2.4), newest sample first (read-only array).

        mid-point: L = n_s, w[j] = t_s g⁽ⁿ⁾((j+½)t_s); trapezoidal: L = n_s+1, nodes j·t_s, end
        weights halved; analytic: L = n_s, w[j] = ∫_{j t_s}^{(j+1) t_s} g⁽ⁿ⁾(τ)dτ exactly (the signal
        held at its mid-interval sample, as AlgDiff's "analytic"). Φ_n = t_sⁿ/n!·Σ_j w[j](−j)ⁿ makes
        the estimate exact for x(t) = tⁿ/n! (thesis (2.4)).
        """
        n = self._refuse(order)
        cached = self._cache.get(n)
        if cached is not None:
            return cached
        raw, phi = self._raw(n, self.n_s)
        if not _normalisable(raw, phi, n, self.fs):
            longer = next(
                (m for m in range(self.n_s + 1, self.n_s + 65) if _normalisable(*self._raw(n, m), n, self.fs)), None
            )
            need = f"n_s >= {longer} (window >= {longer / self.fs:.6g} s)" if longer else "a longer window"
            raise InvalidParameter(
                "window",
                f"n_s = {self.n_s} samples cannot estimate derivative order {n} with the {self.method} rule: the "
                f"normalisation Phi_{n} of (2.4) vanishes; needs {need}, i.e. a lower omega_c",
            )
        w = raw / phi
        w.setflags(write=False)
        self._cache[n] = w
        return w

    def _raw(self, n: int, ns: int) -> tuple[np.ndarray, float]:
        """(w_n up to its scale, Φ_n from the same values) of (2.4) for a window of ``ns`` samples."""
        a, b, N, th = self.alpha, self.beta, self.N, self.theta
        if self.method == "midpoint":
            raw = kernel_u(a, b, N, th, n, (np.arange(ns) + 0.5) / ns)
        elif self.method == "analytic":
            raw = np.diff(kernel_u(a, b, N, th, n - 1, np.arange(ns + 1) / ns))
        else:
            raw = kernel_u(a, b, N, th, n, np.arange(ns + 1) / ns)
            raw[0] *= 0.5
            raw[-1] *= 0.5
        # The scale t_s/T^{n+1} of w_n cancels in w_n/Φ_n, so Φ is formed from the raw values.
        j = np.arange(raw.size, dtype=float)
        return raw, float(np.sum(raw * (-j / self.fs) ** n)) / math.factorial(n)  # pairwise sum, no BLAS threads


def _normalisable(raw: np.ndarray, phi: float, n: int, fs: float) -> bool:
    """Whether Φ_n is a usable divisor: finite and not lost to cancellation (a window of a few
    samples can sample g⁽ⁿ⁾ where its terms cancel exactly, e.g. α = 3, β = 1, n = 1 at n_s = 2:
    the second mid-point falls on the kernel's peak, where g′ = 0)."""
    scale = float(np.sum(np.abs(raw * (np.arange(raw.size) / fs) ** n))) / math.factorial(n)
    return math.isfinite(phi) and abs(phi) > 1e-9 * scale


def whole_samples(x: float) -> int:
    """floor(x) as an int, except that x within 1e-6 of an integer is that integer.

    A window given as n_s/f_s (e.g. 0.145 s at 200 Hz → 28.999999999999996) keeps all n_s samples.
    """
    nearest = round(x)
    return int(nearest) if abs(x - nearest) <= _INTEGER_TOL else math.floor(x)


def design(
    *,
    alpha: float,
    beta: float,
    fs: float,
    omega_c: float | None = None,
    window: float | None = None,
    N: int = 0,
    theta: float | None = None,
    method: str = "midpoint",
) -> Differentiator:
    """Design an algebraic differentiator from exactly one of ``omega_c`` [rad/s] or ``window`` [s].

    n_s = floor(T·f_s) (see :func:`whole_samples`), T = n_s/f_s, and ``omega_c_actual`` is the
    cutoff of that T by Othmane et al. (2022, eq. (31)). ϑ defaults to the largest root of
    P_{N+1}^{(α,β)} for N > 0 and must stay unset for N = 0. Raises :class:`InvalidParameter`.
    """
    a = check_finite("alpha", alpha, "a finite number > -1")
    b = check_finite("beta", beta, "a finite number > -1")
    for name, value in (("alpha", a), ("beta", b)):
        if not -1.0 < value <= MAX_EXPONENT:
            raise InvalidParameter(name, f"must be > -1 and <= {MAX_EXPONENT:g}, got {value!r}")
    f = check_positive("fs", fs)
    if isinstance(N, bool) or not float(check_finite("N", N, "an integer >= 0")).is_integer() or not 0 <= N <= MAX_N:
        raise InvalidParameter("N", f"must be an integer in 0..{MAX_N}, got {N!r}")
    n_poly = int(N)
    if method not in METHODS:
        raise InvalidParameter("method", f"must be one of {', '.join(METHODS)}, got {method!r}")
    if n_poly == 0:
        if theta is not None:
            raise InvalidParameter("theta", f"is only a parameter for N > 0; leave it unset for N = 0, got {theta!r}")
        th = default_theta(a, b, 0)
    elif theta is None:
        th = default_theta(a, b, n_poly)
    else:
        th = check_finite("theta", theta, "in [-1, 1]")
        if not -1.0 <= th <= 1.0:
            raise InvalidParameter("theta", f"must be in [-1, 1], got {theta!r}")
    log_k = log_cutoff_product(a, b, n_poly, th)
    if not math.isfinite(log_k):
        raise InvalidParameter("theta", f"gives no defined cutoff frequency for N = {n_poly}, got {th!r}")
    k_c = math.exp(log_k)  # ω_c·T
    if (omega_c is None) == (window is None):
        got = "both" if omega_c is not None else "neither"
        raise InvalidParameter("omega_c", f"give exactly one of omega_c [rad/s] and window [s], got {got}")
    field_name = "omega_c" if omega_c is not None else "window"
    samples = (
        k_c / check_positive("omega_c", omega_c) * f if omega_c is not None else check_positive("window", window) * f
    )
    n_min = max(2, math.ceil(k_c / math.pi))  # ω_c,actual = k_c·f_s/n_s ≤ π·f_s
    if samples > MAX_SAMPLES:
        limit = f">= {k_c * f / MAX_SAMPLES:.6g} rad/s" if omega_c is not None else f"<= {MAX_SAMPLES / f:.6g} s"
        raise InvalidParameter(field_name, f"must be {limit} (n_s <= {MAX_SAMPLES}), got {omega_c or window!r}")
    n_s = whole_samples(samples)
    if n_s < n_min:
        limit = f"<= {k_c * f / n_min:.6g} rad/s" if omega_c is not None else f">= {n_min / f:.6g} s"
        reason = (
            f"n_s >= 2 samples at fs = {f:g} Hz"
            if n_min == 2
            else f"n_s >= {n_min} at fs = {f:g} Hz: a realised cutoff <= Nyquist pi*fs = {math.pi * f:.6g} rad/s"
        )
        raise InvalidParameter(field_name, f"must be {limit} ({reason}), got {omega_c or window!r} (n_s = {n_s})")
    T = n_s / f
    return Differentiator(
        alpha=a,
        beta=b,
        N=n_poly,
        theta=th,
        fs=f,
        n_s=n_s,
        method=method,
        window_s=T,
        delay_s=(1.0 - th) / 2.0 * T if n_poly else (a + 1.0) / (a + b + 2.0) * T,
        omega_c_actual=k_c / T,
    )
