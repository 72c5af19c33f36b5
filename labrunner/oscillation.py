"""Instability a safety routine may miss: input pinned at a limit, saturated or growing oscillations.

The thesis judges stability by its |du/dt| routine (Sec. 3.3): a run it aborts was unstable. A rig
without such a routine (the valve of paper 1) lets an unstable loop run into its input limits and
oscillate there — a bang-bang limit cycle between the controller's floor and i_max — and such a run
"completes". This detector classifies a run from its logged input u and error e alone, with no
rig-specific knowledge beyond the input's limits [lo, hi]:

- **pinned**: an input sits within ``tolerance`` of the span at a limit for at least
  ``pinned_share`` of the run (the loop has lost authority);
- **saturated oscillation**: an input enters a limit band at least ``min_hits`` (5) times and at
  least ``hit_rate`` (2) times per second, its entries spread over at least (min_hits − 1)/hit_rate
  seconds or half the run, whichever is shorter (a limit cycle, e.g. paper 1's runs above the
  stability region or the thesis's ±12 V switching in 2.5 s angle runs with the safety routine off,
  whose entries start after the 0.5 s rest — not the plate's currents chattering at 0 A for 80 ms
  as the lift starts);
- **growing oscillation**: the RMS of the input's sample-to-sample change Δu rises quarter by
  quarter of the run (r₂ < r₃ < r₄) to ``growth`` × its value in the second quarter (the first is
  left out: runs start at rest). A growing oscillation adds energy at high frequency, where
  Δu sees it and the smooth reference transitions barely register;
- **sustained oscillation**, whatever its amplitude relative to the limits (paper 1 Sec. 5.2: on
  line (A) "the system starts oscillating, but the current is not reaching its maximum value"):
  the run is cut into ``segments`` pieces; in one of them the input, less its straight-line trend,
  repeats itself — its autocorrelation after the first zero crossing reaches ``periodicity`` at a
  lag of at most a third of the piece (three periods or more) — with a peak-to-peak amplitude
  (2√2 σ) of at least ``amplitude`` × the input's own range over the run (so that a periodic
  pattern of quantisation or rounding far below what the input does is not an oscillation), neither
  dying out nor setting in within the piece (σ of each half ≥ ``decay`` × the other's: a ring-down
  that starts mid-piece, as the plate's after a fault, is not sustained; a growing oscillation is
  the growth rule's).
  ``periodicity`` is that largest autocorrelation (0 where no piece qualifies).

A growth over a run that holds only a period or two of the oscillation (the thesis's 2.5 s angle
runs against a loop of about 1 Hz) is one swing, not a trend: where the growth rule is the only
one to fire and the run holds fewer than ``min_periods`` periods of the frequency at which Δu's
spectrum (second half of the run) peaks, ``undecided`` is 1.0 — the run is still flagged (the maps
show it), but a verdict that depends on it is undecided (:mod:`labrunner.reproduce.verdict`).

Pure numpy; the metrics of :mod:`labrunner.metrics` call it once per run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Columns :func:`detect` adds to a run's metrics.
DETECTOR_METRICS = (
    "pinned_share",
    "limit_hits_per_s",
    "du_growth",
    "periodicity",
    "oscillating",
    "undecided",
    "detector_version",
)
#: Raised whenever a rule changes, so that runs judged by an older detector are recomputed
#: (:func:`labrunner.reproduce.run.stale_detector`). 2: short-run limit cycles, ring-downs, ``undecided``.
VERSION = 2


@dataclass(frozen=True)
class Detector:
    """Thresholds of the detector (defaults chosen on the twins: see tests/test_oscillation.py)."""

    tolerance: float = 0.01  # share of the input span [lo, hi] that counts as "at the limit"
    pinned_share: float = 0.5  # pinned: at a limit for at least this share of the samples
    min_hits: int = 5  # saturated oscillation: at least this many entries into a limit band ...
    hit_rate: float = 2.0  # ... and at least this many per second [1/s]: the plate's currents touch 0 A
    # about once a second while it descends under gravity (paper 2's lift), a limit cycle 3-15 times
    growth: float = 2.0  # growing: RMS(Δu) of the last quarter ≥ growth × the second quarter's
    segments: int = 5  # sustained: pieces of the run, each searched for ≥ 3 periods of one oscillation
    periodicity: float = 0.7  # sustained: autocorrelation at the period (hand-labelled runs: see tests)
    amplitude: float = 0.1  # sustained: peak-to-peak ≥ this share of the input's range over the run
    decay: float = 0.7  # sustained: the piece's second half keeps at least this share of the first's σ
    min_periods: float = 3.0  # growth alone decides only on runs holding at least this many periods

    def detect(self, u: np.ndarray, lo: np.ndarray, hi: np.ndarray, fs: float) -> dict[str, float]:
        """Detector metrics of one run: ``u`` (n_inputs, K) with limits ``lo``, ``hi`` (n_inputs,).

        ``oscillating`` is 1.0 when any rule fires, else 0.0 (NaN when the run has no input).
        Inputs with an infinite limit are never "at" that limit.
        """
        u = np.atleast_2d(np.asarray(u, dtype=float))
        n, k = u.shape
        if n == 0 or k < 8:
            return {name: float("nan") for name in DETECTOR_METRICS}
        lo = np.broadcast_to(np.asarray(lo, dtype=float), (n,))[:, None]
        hi = np.broadcast_to(np.asarray(hi, dtype=float), (n,))[:, None]
        span = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
        band = self.tolerance * span
        at_hi = np.isfinite(hi) & (span > 0) & (u >= hi - band)
        at_lo = np.isfinite(lo) & (span > 0) & (u <= lo + band)
        at_limit = at_hi | at_lo
        pinned = float(at_limit.mean(axis=1).max())
        entering = (np.diff(at_hi.astype(np.int8), axis=1) == 1) | (np.diff(at_lo.astype(np.int8), axis=1) == 1)
        entries = entering.sum(axis=1)
        worst = int(entries.argmax())
        hits = int(entries[worst])
        rate = hits * fs / k
        where = np.flatnonzero(entering[worst])
        spread = (where[-1] - where[0]) / fs if hits else 0.0
        growth = _growth(u)
        periodic = max(self.sustained(row) for row in u)
        other = (
            pinned >= self.pinned_share
            or (
                hits >= self.min_hits
                and rate >= self.hit_rate
                and spread >= min((self.min_hits - 1) / self.hit_rate, 0.5 * k / fs)
            )
            or periodic >= self.periodicity
        )
        grows = growth >= self.growth
        return {
            "pinned_share": pinned,
            "limit_hits_per_s": float(rate),
            "du_growth": growth,
            "periodicity": periodic,
            "oscillating": float(other or grows),
            "undecided": float(grows and not other and periods(u, fs) < self.min_periods),
            "detector_version": float(VERSION),
        }

    def sustained(self, x: np.ndarray) -> float:
        """The largest autocorrelation at a period of ≥ 3 repeats in one piece of ``x`` (one input)
        whose oscillation is at least ``amplitude`` × the range of ``x``; 0 where none qualifies."""
        span = float(np.ptp(x)) if x.size else 0.0
        n = x.size // self.segments
        if span <= 0.0 or n < 16:
            return 0.0
        pieces = x[: n * self.segments].reshape(self.segments, n)
        t = np.arange(n) - (n - 1) / 2.0
        slope = pieces @ t / (t @ t)
        y = pieces - pieces.mean(axis=1, keepdims=True) - slope[:, None] * t
        big = 2.0 * np.sqrt(2.0) * y.std(axis=1) >= self.amplitude * span
        if not big.any():
            return 0.0
        half = n // 2
        first, second = y[:, :half].std(axis=1), y[:, half:].std(axis=1)
        # neither dying out nor starting mid-piece (a ring-down after a fault at the piece's middle)
        kept = (second >= self.decay * first) & (first >= self.decay * second)
        y = y[big & kept]
        if not len(y):
            return 0.0
        f = np.fft.rfft(y, 2 * n, axis=1)
        r = np.fft.irfft(f * np.conj(f), axis=1)[:, :n]
        r = r / r[:, :1] * n / (n - np.arange(n))  # normalised, unbiased
        best = 0.0
        for row in r[:, : n // 3]:
            below = np.flatnonzero(row < 0.0)
            if below.size:
                best = max(best, float(row[below[0] :].max()))
        return best


def periods(u: np.ndarray, fs: float) -> float:
    """How many periods of its dominant oscillation the run ``u`` (n_inputs, K) holds: K / fs times the
    frequency at which the spectrum of Δu over the run's second half (Hann window, inputs summed) peaks."""
    du = np.diff(u[:, u.shape[1] // 2 :], axis=1)
    if du.shape[1] < 8:
        return 0.0
    power = np.square(np.abs(np.fft.rfft(du * np.hanning(du.shape[1]), axis=1))).sum(axis=0)
    power[0] = 0.0
    return float(np.fft.rfftfreq(du.shape[1], 1.0 / fs)[int(power.argmax())] * u.shape[1] / fs)


def _growth(u: np.ndarray) -> float:
    """r₄ / r₂ of the RMS of Δu per quarter when it rises monotonically from r₂ on, else 0."""
    du = np.diff(u, axis=1)
    quarter = du.shape[1] // 4
    r = np.sqrt(np.mean(np.square(du[:, : 4 * quarter].reshape(du.shape[0], 4, quarter)), axis=(0, 2)))
    if not (0.0 < r[1] < r[2] < r[3]):
        return 0.0
    return float(r[3] / r[1])
