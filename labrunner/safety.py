"""Safety monitors, checked every tick on the whole batch.

The thesis's routine (Sec. 3.3, "Safety routine") stops a run when the commanded input changes too
fast, |u̇[k]| ≥ 120 V/s, with u̇ estimated by an algebraic differentiator (N = 0, α = β = 6,
ω_c = 200 rad/s, mid-point). Around it: bounds on outputs and inputs (air gap, currents, flow),
non-finite values, and a run-time limit. A tripped run is reported with the monitor, the time,
the offending value and the threshold; the engine sends it to the rig's safe state in the same
tick.

Limits come from the rig file's ``[safety]`` section, overridden by the campaign's ``[safety]``;
both are validated by :class:`labrunner.safety_config.SafetyConfig` (re-exported here).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from labrunner._ufunc import clip, count_nonzero
from labrunner.differentiators import Differentiator, StreamingFIR, design, pad_taps
from labrunner.rigs.base import RigInfo
from labrunner.safety_config import SafetyConfig

__all__ = ["MONITORS", "SafetyConfig", "SafetyMonitor", "Verdict"]

#: every monitor a verdict may name, in the order verdicts take precedence (docs/control-laws.md);
#: the bounds monitors and du_dt add ":<signal>" when their group has more than one signal
MONITORS = (
    "non_finite_input",
    "non_finite_output",
    "output_low",
    "output_high",
    "input_low",
    "input_high",
    "du_dt",
    "run_time",
)


@dataclass(frozen=True)
class Verdict:
    """Why a run was aborted: which monitor, when [s], the value seen and the threshold."""

    monitor: str
    time: float
    value: float
    threshold: float


class _Screen:
    """Flags values outside their closed bounds [lo, hi] (B, n) or non-finite, in one clip: finite
    values inside are exactly those a clip to the bounds' finite part leaves unchanged (NaN ≠ NaN,
    ±inf ≠ ±max, out of bounds ≠ its bound). The screen is the every-tick part of the monitors;
    tests/test_safety.py checks it tick by tick against the plain monitors."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        big = np.finfo(float).max
        self.lo, self.hi = np.maximum(lo, -big), np.minimum(hi, big)
        self._clipped = np.zeros(lo.shape)
        self._off = np.zeros(lo.shape, dtype=bool)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(B, n) flags, valid until the next call."""
        return np.not_equal(clip(x, self.lo, self.hi, out=self._clipped), x, out=self._off)


class SafetyMonitor:
    """All monitors of a batch of B runs; ``check`` once per tick returns newly tripped runs.
    :meth:`reset` starts them (and forms the du/dt estimator's taps) before the first ``check``."""

    def __init__(self, configs: Sequence[SafetyConfig], rig_info: RigInfo, fs: float) -> None:
        self.B = len(configs)
        self.fs = float(fs)
        self.n_inputs = len(rig_info.inputs)
        self._max_du_dt = np.array([np.inf if c.max_du_dt is None else c.max_du_dt for c in configs])
        self._rate: StreamingFIR | None = None  # formed by the first reset from these designs
        self._rate_designs: list[Differentiator] = []
        if np.isfinite(self._max_du_dt).any():
            by_design: dict[tuple[float, float, float], Differentiator] = {}  # one per distinct (α, β, ω_c)
            for c in configs:
                key = (c.du_dt_alpha, c.du_dt_beta, c.du_dt_omega_c)
                if key not in by_design:
                    by_design[key] = design(alpha=key[0], beta=key[1], omega_c=key[2], fs=self.fs)
                    by_design[key].check_weights(1)
                self._rate_designs.append(by_design[key])
        self._out_lo, self._out_hi = self._bounds(configs, rig_info.outputs, "output_bounds")
        self._in_lo, self._in_hi = self._bounds(configs, rig_info.inputs, "input_bounds")
        self._has_output_bounds = bool(np.isfinite(self._out_lo).any() or np.isfinite(self._out_hi).any())
        self._has_input_bounds = bool(np.isfinite(self._in_lo).any() or np.isfinite(self._in_hi).any())
        self._out_names = [s.name for s in rig_info.outputs]
        # signals derived from the outputs (the plate's air gaps), screened only where bounded
        self._der_lo, self._der_hi = self._bounds(configs, rig_info.derived, "output_bounds")
        self._der_names = [d.name for d in rig_info.derived]
        self._der_weights_T: np.ndarray | None = None  # (n_out, n_derived): derived = y · weights_T
        if np.isfinite(self._der_lo).any() or np.isfinite(self._der_hi).any():
            self._der_weights_T = np.ascontiguousarray(np.array([d.weights for d in rig_info.derived], dtype=float).T)
            self._der_values = np.zeros(self._der_lo.shape)
            self._der_screen = _Screen(self._der_lo, self._der_hi)
        self._in_names = [s.name for s in rig_info.inputs]
        self._max_t = np.array([np.inf if c.max_duration is None else c.max_duration for c in configs])
        self.verdicts: list[Verdict | None] = [None] * self.B
        # the every-tick screen of u and y side by side (B, n_in + n_out)
        self._uy = np.zeros((self.B, self.n_inputs + len(rig_info.outputs)))
        self._screen = _Screen(np.hstack([self._in_lo, self._out_lo]), np.hstack([self._in_hi, self._out_hi]))
        self._lim = np.repeat(self._max_du_dt, self.n_inputs)  # per rate-estimator row
        self._rate_abs = np.zeros(self.B * self.n_inputs)
        self._rate_hit = np.zeros(self.B * self.n_inputs, dtype=bool)
        self._next_time_limit = float(self._max_t.min())  # the earliest run-time limit of a run not yet tripped

    @staticmethod
    def _bounds(configs: Sequence[SafetyConfig], signals: Sequence, key: str) -> tuple[np.ndarray, np.ndarray]:
        lo = np.full((len(configs), len(signals)), -np.inf)
        hi = np.full((len(configs), len(signals)), np.inf)
        for i, c in enumerate(configs):
            for j, s in enumerate(signals):
                if s.name in getattr(c, key):
                    lo[i, j], hi[i, j] = getattr(c, key)[s.name]
        return lo, hi

    def reset(self, u0: np.ndarray) -> None:
        """Start the rate estimator from a steady input ``u0`` (B, n_inputs)."""
        if self._rate_designs and self._rate is None:  # its taps, once: a monitor built only to validate needs none
            per_run = pad_taps([d.weights(1) for d in self._rate_designs])  # (B, L)
            self._rate = StreamingFIR(np.repeat(per_run, self.n_inputs, axis=0))
        if self._rate is not None:
            self._rate.reset(self.B * self.n_inputs, fill=np.asarray(u0, float).reshape(-1))
        self.verdicts = [None] * self.B
        self._next_time_limit = float(self._max_t.min())

    def check(self, k: int, u: np.ndarray, y: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Check tick ``k`` (commanded ``u`` (B, n_in), measured ``y`` (B, n_out)); return newly tripped (B,).

        A screen of a few array operations clears the usual tick in which nothing trips; only a
        tick the screen flags runs every monitor by itself and builds the verdicts of the active
        runs that trip (which monitor, value, threshold).
        """
        t = k / self.fs
        uy = self._uy
        uy[:, : self.n_inputs] = u
        uy[:, self.n_inputs :] = y
        off = self._screen(uy)
        odd = count_nonzero(off) > 0
        flagged = odd and self._active_hit(off, active)
        if self._der_weights_T is not None:
            d_off = self._der_screen(np.dot(y, self._der_weights_T, out=self._der_values))
            flagged = flagged or (count_nonzero(d_off) > 0 and self._active_hit(d_off, active))
        rate = None
        if self._rate_designs:  # never skipped unstarted: without reset() there is no estimator to step
            # the estimator sees non-finite inputs as 0 (a NaN would stay in its window for good)
            x = np.nan_to_num(u, nan=0.0, posinf=0.0, neginf=0.0) if odd else u
            rate = np.abs(self._rate.step(np.reshape(x, -1)), out=self._rate_abs)
            hit = np.greater_equal(rate, self._lim, out=self._rate_hit)
            flagged = flagged or (
                count_nonzero(hit) > 0 and self._active_hit(hit.reshape(self.B, self.n_inputs), active)
            )
        if not (flagged or t >= self._next_time_limit):
            return np.zeros(self.B, dtype=bool)
        tripped = self._verdicts(t, u, y, active, None if rate is None else rate.reshape(self.B, self.n_inputs))
        open_runs = [i for i, v in enumerate(self.verdicts) if v is None]
        self._next_time_limit = float(self._max_t[open_runs].min()) if open_runs else np.inf
        return tripped

    def _active_hit(self, hit: np.ndarray, active: np.ndarray) -> bool:
        """Whether ``hit`` (B, n), known to hold some True, holds one for an active run."""
        return count_nonzero(active) == self.B or count_nonzero(hit & active[:, None]) > 0

    def _verdicts(
        self, t: float, u: np.ndarray, y: np.ndarray, active: np.ndarray, rate: np.ndarray | None
    ) -> np.ndarray:
        """Every monitor by itself on a flagged tick: the active runs that trip now, with their verdicts."""
        lim = None if rate is None else np.broadcast_to(self._max_du_dt[:, None], rate.shape)
        duration = self._max_t[:, None]
        # (monitor, hit (B, n), value, threshold, signal names), in the order verdicts take precedence
        checks = [
            ("non_finite_input", ~np.isfinite(u), u, 0.0, None),
            ("non_finite_output", ~np.isfinite(y), y, 0.0, None),
        ]
        if self._has_output_bounds:
            checks += [
                ("output_low", y < self._out_lo, y, self._out_lo, self._out_names),
                ("output_high", y > self._out_hi, y, self._out_hi, self._out_names),
            ]
        if self._der_weights_T is not None:
            d = np.dot(y, self._der_weights_T)
            checks += [
                ("output_low", d < self._der_lo, d, self._der_lo, self._der_names),
                ("output_high", d > self._der_hi, d, self._der_hi, self._der_names),
            ]
        if self._has_input_bounds:
            checks += [
                ("input_low", u < self._in_lo, u, self._in_lo, self._in_names),
                ("input_high", u > self._in_hi, u, self._in_hi, self._in_names),
            ]
        if rate is not None:
            checks.append(("du_dt", rate >= lim, rate, lim, self._in_names))
        checks.append(("run_time", t >= duration, np.full((self.B, 1), t), duration, None))
        tripped = np.zeros(self.B, dtype=bool)
        for monitor, hit, value, threshold, names in checks:
            runs = np.flatnonzero(hit.any(axis=1) & active & ~tripped)
            for i in runs:  # only runs that trip now: rare, so a loop here costs nothing per tick
                j = int(np.argmax(hit[i]))
                label = monitor if names is None or len(names) == 1 else f"{monitor}:{names[j]}"
                limit = np.broadcast_to(threshold, hit.shape)[i, j]
                self.verdicts[i] = Verdict(label, t, float(np.broadcast_to(value, hit.shape)[i, j]), float(limit))
                tripped[i] = True
        return tripped
