"""Reference and open-loop input trajectories with exact derivatives up to order 3.

Every trajectory is evaluated by one vectorised routine over a *stack* of trajectories of the same
type, so that a batch of B runs (each with its own levels, times or delay) is evaluated without a
Python loop over runs: :class:`Reference` groups the runs' trajectories by type and evaluates each
group at once. A single trajectory's :meth:`Trajectory.evaluate` is the same routine on a stack of
one.

- :class:`Setpoints`: set-point transitions by polynomials of degree 5 with zero velocity and
  acceleration at both ends (thesis ch. 3, Fig. 3.4; paper 1 Sec. 5.1; paper 2 Sec. 4.1), with
  hold times between them; optionally delayed by the differentiator's delay δ_t so that the
  delayed estimate ŷ(t) ≈ y(t − δ_t) is compared with a reference delayed alike (paper 2,
  Sec. 4.3.1).
- :class:`Steps`: piecewise-constant levels (open-loop step experiments, thesis Sec. 3.2).
- :class:`Sine`: ``offset + amplitude·sin(2π f t)`` (open-loop identification, thesis Fig. 3.1).
- :class:`Table`: samples at f_s, read by tick index (a device-loop run description's sample
  table, docs/device-loop.md): any trajectory sampled at the run's ticks is its table.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter, check_finite


def _as_times(field_name: str, value: float | Sequence[float], n: int, *, positive: bool) -> tuple[float, ...]:
    """A scalar broadcast to ``n`` times, or a list of exactly ``n`` times [s]; all ≥ 0 (> 0 if positive)."""
    values = [value] * n if np.ndim(value) == 0 else list(value)  # type: ignore[arg-type]
    if len(values) != n:
        raise InvalidParameter(field_name, f"needs 1 or {n} values, got {len(values)}")
    out = tuple(check_finite(field_name, v) for v in values)
    for v in out:
        if v < 0 or (positive and v == 0):
            raise InvalidParameter(field_name, f"must be {'> 0' if positive else '>= 0'} s, got {v!r}")
    return out


class Trajectory(abc.ABC):
    """A scalar time function with exact derivatives; ``evaluate(t)`` → (len(t), 4)."""

    delay_s: float

    @property
    @abc.abstractmethod
    def duration(self) -> float:
        """Time [s] after which the trajectory is constant (including its delay)."""

    @abc.abstractmethod
    def _params(self) -> tuple[np.ndarray, ...]:
        """This trajectory's parameters as 1-d arrays (padded by :meth:`_stack` to a common length)."""

    @staticmethod
    @abc.abstractmethod
    def _eval(params: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        """Evaluate a stack of R trajectories (params of shape (R, S)) at ``t`` (..., R) → (..., R, 4)."""

    @classmethod
    def _stack(cls, trajectories: Sequence[Trajectory]) -> tuple[np.ndarray, ...]:
        per_run = [tr._params() for tr in trajectories]
        stacked = []
        for i in range(len(per_run[0])):
            width = max(p[i].size for p in per_run)
            rows = np.zeros((len(per_run), width))
            for r, p in enumerate(per_run):
                rows[r, : p[i].size] = p[i]
            stacked.append(rows)
        return tuple(stacked)

    def evaluate(self, t: np.ndarray | float) -> np.ndarray:
        """Value and derivatives 1..3 at times ``t`` [s]: array (len(t), 4)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self._eval(self._stack([self]), t[:, None])[:, 0, :]


def _poly5(tau: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Unit poly-5 step p(τ) = 10τ³ − 15τ⁴ + 6τ⁵ and dp/dτ, d²p/dτ², d³p/dτ³ (τ clipped to [0, 1]).

    p' and p'' vanish at both ends; p''' jumps there, so it is set to 0 outside the open interval.
    """
    t2 = tau * tau
    p = t2 * tau * (10.0 - 15.0 * tau + 6.0 * t2)
    d1 = 30.0 * t2 * (1.0 - tau) ** 2
    d2 = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau)
    d3 = np.where(inside, 60.0 * (1.0 - 6.0 * tau + 6.0 * t2), 0.0)
    return np.stack([p, d1, d2, d3], axis=-1)


@dataclass(frozen=True)
class Setpoints(Trajectory):
    """Levels joined by poly-5 transitions: hold[0], transition to levels[1], hold[1], …, hold[-1].

    ``transition`` has one time per transition (or one for all) [s], ``hold`` one time per level
    (or one for all) [s]; ``delay_s`` shifts the whole trajectory later (value levels[0] before).
    """

    levels: tuple[float, ...]
    transition: tuple[float, ...]
    hold: tuple[float, ...]
    delay_s: float = 0.0

    @classmethod
    def build(
        cls,
        levels: Sequence[float],
        transition: float | Sequence[float],
        hold: float | Sequence[float],
        delay_s: float = 0.0,
        *,
        field_prefix: str = "reference",
    ) -> Setpoints:
        """Validated constructor; errors name ``<field_prefix>.levels`` etc."""
        if np.ndim(levels) != 1 or len(levels) < 1:
            raise InvalidParameter(f"{field_prefix}.levels", f"must be a non-empty list of numbers, got {levels!r}")
        lv = tuple(check_finite(f"{field_prefix}.levels", v) for v in levels)
        tr = _as_times(f"{field_prefix}.transition", transition, len(lv) - 1, positive=True)
        ho = _as_times(f"{field_prefix}.hold", hold, len(lv), positive=False)
        delay = check_finite(f"{field_prefix}.delay", delay_s)
        if delay < 0:
            raise InvalidParameter(f"{field_prefix}.delay", f"must be >= 0 s, got {delay!r}")
        return cls(lv, tr, ho, delay)

    @property
    def duration(self) -> float:
        return self.delay_s + sum(self.transition) + sum(self.hold)

    def delayed(self, delay_s: float) -> Setpoints:
        """The same trajectory delayed by ``delay_s`` [s] (paper 2, Sec. 4.3.1)."""
        return Setpoints(self.levels, self.transition, self.hold, float(delay_s))

    def _params(self) -> tuple[np.ndarray, ...]:
        starts = (
            self.delay_s
            + np.cumsum(np.asarray(self.hold[:-1]))
            + np.concatenate([[0.0], np.cumsum(self.transition[:-1])])
        )
        steps = np.diff(self.levels)
        return np.array([self.levels[0]]), starts, np.asarray(self.transition, float), steps

    @classmethod
    def _stack(cls, trajectories: Sequence[Trajectory]) -> tuple[np.ndarray, ...]:
        first, starts, durations, steps = super()._stack(trajectories)
        return first[:, 0], starts, np.where(durations > 0, durations, 1.0), steps  # padding: Δ = 0, T = 1

    @staticmethod
    def _eval(params: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        first, starts, durations, steps = params  # (R,), (R, S), (R, S), (R, S)
        x = (t[..., None] - starts) / durations  # (..., R, S)
        tau = np.clip(x, 0.0, 1.0)
        p = _poly5(tau, (x >= 0.0) & (x < 1.0))  # (..., R, S, 4)
        scale = steps[..., None] / durations[..., None] ** np.arange(4)  # Δ / Tⁿ
        out = np.sum(p * scale, axis=-2)
        out[..., 0] += first
        return out


@dataclass(frozen=True)
class Steps(Trajectory):
    """Piecewise-constant levels, levels[i] during durations[i] [s]; the last level is held on."""

    levels: tuple[float, ...]
    durations: tuple[float, ...]
    delay_s: float = 0.0

    @classmethod
    def build(
        cls, levels: Sequence[float], durations: float | Sequence[float], *, field_prefix: str = "reference"
    ) -> Steps:
        if np.ndim(levels) != 1 or len(levels) < 1:
            raise InvalidParameter(f"{field_prefix}.levels", f"must be a non-empty list of numbers, got {levels!r}")
        lv = tuple(check_finite(f"{field_prefix}.levels", v) for v in levels)
        return cls(lv, _as_times(f"{field_prefix}.durations", durations, len(lv), positive=True))

    @property
    def duration(self) -> float:
        return self.delay_s + sum(self.durations)

    def _params(self) -> tuple[np.ndarray, ...]:
        starts = self.delay_s + np.concatenate([[0.0], np.cumsum(self.durations[:-1])])
        return np.array([self.levels[0]]), starts[1:], np.diff(self.levels)

    @staticmethod
    def _eval(params: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        first, starts, steps = params
        value = first[:, 0] + np.sum(np.where(t[..., None] >= starts, steps, 0.0), axis=-1)
        out = np.zeros(value.shape + (4,))
        out[..., 0] = value
        return out


@dataclass(frozen=True)
class Sine(Trajectory):
    """``offset + amplitude·sin(2π·frequency·t)`` for 0 ≤ t < duration_s, ``offset`` afterwards."""

    amplitude: float
    frequency_hz: float
    duration_s: float
    offset: float = 0.0
    delay_s: float = 0.0

    @classmethod
    def build(
        cls,
        amplitude: float,
        frequency: float,
        duration: float,
        offset: float = 0.0,
        *,
        field_prefix: str = "reference",
    ) -> Sine:
        f = check_finite(f"{field_prefix}.frequency", frequency)
        d = check_finite(f"{field_prefix}.duration", duration)
        if f <= 0:
            raise InvalidParameter(f"{field_prefix}.frequency", f"must be > 0 Hz, got {frequency!r}")
        if d <= 0:
            raise InvalidParameter(f"{field_prefix}.duration", f"must be > 0 s, got {duration!r}")
        return cls(
            check_finite(f"{field_prefix}.amplitude", amplitude), f, d, check_finite(f"{field_prefix}.offset", offset)
        )

    @property
    def duration(self) -> float:
        return self.delay_s + self.duration_s

    def _params(self) -> tuple[np.ndarray, ...]:
        return (
            np.array([self.amplitude, 2.0 * np.pi * self.frequency_hz, self.duration_s, self.offset, self.delay_s]),
        )

    @staticmethod
    def _eval(params: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        amp, w, dur, offset, delay = params[0].T
        s = t - delay
        on = (s >= 0.0) & (s < dur)
        phase = w * s
        sin, cos = np.sin(phase), np.cos(phase)
        out = np.stack([amp * sin, amp * w * cos, -amp * w**2 * sin, -amp * w**3 * cos], axis=-1)
        out = np.where(on[..., None], out, 0.0)
        out[..., 0] += offset
        return out


@dataclass(frozen=True, eq=False)
class Table(Trajectory):
    """Samples ``rows`` (n, 4: value and derivatives 1..3) at ``fs``: row k at t = k/f_s, the
    nearest row to t, the last one held after the end (as firmware reads a table by tick index)."""

    fs: float
    rows: np.ndarray
    delay_s: float = 0.0

    @classmethod
    def sample(cls, trajectory: Trajectory, fs: float, ticks: int) -> Table:
        """``trajectory`` at ticks 0..ticks−1, cut after the last change (the held row ends it)."""
        rows = trajectory.evaluate(np.arange(ticks) / fs)
        changed = np.flatnonzero(np.any(rows != rows[-1], axis=1))
        n = int(changed[-1]) + 2 if changed.size else 1  # one row of the final value after the last change
        return cls(float(fs), rows[:n].copy())

    @property
    def duration(self) -> float:
        return (len(self.rows) - 1) / self.fs

    def _params(self) -> tuple[np.ndarray, ...]:
        return np.array([self.fs, len(self.rows)]), self.rows.ravel()

    @staticmethod
    def _eval(params: tuple[np.ndarray, ...], t: np.ndarray) -> np.ndarray:
        head, flat = params  # (R, 2), (R, 4·n_max)
        k = np.clip(np.rint(t * head[:, 0]), 0, head[:, 1] - 1).astype(np.int64)  # (..., R)
        runs = np.arange(flat.shape[0])[:, None]
        return flat[runs, 4 * k[..., None] + np.arange(4)]  # (..., R, 4)


class Reference:
    """The batched reference of B runs with n_outputs trajectories each.

    ``evaluate(t)`` with t of shape (K,) [s] → (K, B, n_outputs, 4): value and derivatives 1..3.
    Equal trajectories (a γ–k_p grid shares one) are evaluated once; the distinct ones are grouped
    by type and each group is evaluated in one vectorised call. The array is stored derivative
    by derivative (a (K, 4, B, n_outputs) block seen through a transposed view), so that a tick's
    value or derivative ``r[k][:, :, j]``, which a controller reads every tick, is contiguous.
    """

    def __init__(self, trajectories: Sequence[Sequence[Trajectory]]) -> None:
        if not trajectories or not trajectories[0]:
            raise InvalidParameter("reference", "needs at least one run and one output")
        n_out = len(trajectories[0])
        if any(len(row) != n_out for row in trajectories):
            raise InvalidParameter("reference", "every run needs the same number of output trajectories")
        self.trajectories = tuple(tuple(row) for row in trajectories)
        self.batch, self.n_outputs = len(trajectories), n_out
        flat = [tr for row in self.trajectories for tr in row]
        distinct = list(dict.fromkeys(flat))
        position = {tr: i for i, tr in enumerate(distinct)}
        self._gather = np.array([position[tr] for tr in flat])
        self._n_distinct = len(distinct)
        self._groups = []
        for kind in dict.fromkeys(type(tr) for tr in distinct):
            index = np.array([i for i, tr in enumerate(distinct) if type(tr) is kind])
            self._groups.append((kind, index, kind._stack([distinct[i] for i in index])))

    @property
    def duration(self) -> float:
        """Time [s] after which every run's reference is constant."""
        return max(tr.duration for row in self.trajectories for tr in row)

    def evaluate(self, t: np.ndarray | float) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty((t.size, self._n_distinct, 4))
        for kind, index, params in self._groups:
            out[:, index, :] = kind._eval(params, t[:, None])
        planes = np.take(np.ascontiguousarray(out.transpose(0, 2, 1)), self._gather, axis=2)  # (K, 4, B·n_outputs)
        return planes.reshape(t.size, 4, self.batch, self.n_outputs).transpose(0, 2, 3, 1)
