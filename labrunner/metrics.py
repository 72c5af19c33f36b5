"""Per-run quality metrics: RMS of the tracking error, input energy, peak input and current.

The thesis (Sec. 3.4.1, 3.5.1) judges a run by the RMS value of its tracking error e and by the
input energy E(u) = Σ_j |u[j]|² (thesis 3.5.1, after Oppenheim and Schafer); paper 2 also uses
the RMS of the delayed, filtered error ê. These functions are pure: they take the logged signals
as arrays and the names of the channels that play each role. The engine computes them for the
ledger's summary as each run ends, and the analysis recomputes them from the logs, with one code.

The engine ends an aborted run's signals at its abort sample (a failed one's where it failed), so
the metrics of a run cut short cover only its part: wherever they are shown (the table, a run's
``metrics`` in the results API, ``inspect``) they carry the suffix :data:`UNTIL_ABORT`
(``rms_error_until_abort``, :func:`as_reported`), so that only whole runs rank by ``rms_error``.

Named windows (a campaign's ``[metrics]`` section, e.g. ``fault = [2.0, 2.5]`` in seconds) give the
same metrics over samples t0 ≤ k/fs < t1 as ``<metric>@<name>`` columns, so a fault's effect or
the hover after a lift-off is measured without the transient around it (paper 2 Table 3). With the
input limits and f_s, the run also gets the oscillation detector's columns
(:mod:`labrunner.oscillation`) — if its controller closes a loop (:func:`closes_loop`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter
from labrunner.oscillation import Detector

DEFAULT_DETECTOR = Detector()  # the thresholds of labrunner.oscillation

#: Metric columns every run gets (NaN where a run has no such channel).
BASE_METRICS = ("rms_error", "rms_error_hat", "input_energy", "max_abs_input", "max_current", "n_samples")
#: Controller kinds whose input does not feed back the measured output (labrunner.control.baselines): an
#: input at its limit there is a commanded step (the ±12 V identification steps), not a loop that lost
#: authority, and u alone cannot tell the two apart; their runs get no detector columns.
OPEN_LOOP_KINDS = frozenset({"open-loop", "valve-ffc"})
UNTIL_ABORT = "_until_abort"  # the suffix of a cut-short run's metrics
CUT_SHORT = ("aborted", "failed")  # outcomes whose run ended before its duration (the engine's words)
_RANKED_PREFIXES = ("rms_", "energy_", "max_")


def ranked(name: str) -> bool:
    """Whether metric ``name`` (``<metric>`` or ``<metric>@<window>``) describes how well a run
    went — the ones a run cut short must not offer for ranking; sample counts do not."""
    base = name.split("@", 1)[0]
    return (base in BASE_METRICS or base.startswith(_RANKED_PREFIXES)) and base != "n_samples"


def closes_loop(config: Mapping[str, object] | None) -> bool:
    """Whether a run's configuration (its ``controller`` section) feeds the output back: only then may the
    oscillation detector judge it (the callers pass no input limits otherwise)."""
    controller = (config or {}).get("controller")
    return not (isinstance(controller, Mapping) and controller.get("kind") in OPEN_LOOP_KINDS)


def as_reported(metrics: Mapping[str, object], status: str | None) -> dict[str, object]:
    """A run's metrics under the names every view uses: a run cut short (:data:`CUT_SHORT`)
    has its :func:`ranked` metrics as ``<metric>_until_abort``."""
    if status not in CUT_SHORT:
        return dict(metrics)
    return {(k + UNTIL_ABORT if ranked(k) else k): v for k, v in metrics.items()}


@dataclass(frozen=True)
class Roles:
    """Which logged channels play which role in the metrics.

    ``errors``: tracking errors e_<output> (y − y_r, in the output's unit);
    ``error_hats``: delayed, filtered errors ê_<output> (paper 2) where logged;
    ``inputs``: rig inputs u (V, A, ...); ``currents``: channels measured in A;
    ``input_limits``: (lo, hi) per input, for the oscillation detector (none: no detector).
    """

    errors: tuple[str, ...]
    inputs: tuple[str, ...]
    error_hats: tuple[str, ...] = ()
    currents: tuple[str, ...] = ()
    input_limits: tuple[tuple[float, float], ...] = ()


def parse_windows(section: Mapping[str, object] | None, field: str = "metrics") -> dict[str, tuple[float, float]]:
    """Named windows of a ``[metrics]`` section: each key a name, each value ``[t0, t1]`` [s], 0 ≤ t0 < t1."""
    windows: dict[str, tuple[float, float]] = {}
    for name, value in dict(section or {}).items():
        where = f"{field}.{name}"
        if not name.replace("_", "").replace("-", "").isalnum():
            raise InvalidParameter(where, "a window name may hold letters, digits, '_' and '-' only")
        if (
            not isinstance(value, (list, tuple))
            or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        ):
            raise InvalidParameter(where, f"must be a window [t0, t1] in seconds, got {value!r}")
        t0, t1 = float(value[0]), float(value[1])
        if not (math.isfinite(t0) and math.isfinite(t1) and 0.0 <= t0 < t1):
            raise InvalidParameter(where, f"needs 0 <= t0 < t1 (finite, in s), got [{t0:g}, {t1:g}]")
        windows[name] = (t0, t1)
    return windows


def _stack(signals: Mapping[str, np.ndarray], names: Sequence[str], k: int) -> np.ndarray:
    """(len(names), k) float array of the first k samples of each named channel."""
    if not names:
        return np.empty((0, k))
    return np.vstack([np.asarray(signals[name], dtype=float)[:k] for name in names])


def _rms_rows(x: np.ndarray) -> tuple[float, np.ndarray]:
    """RMS over all of ``x`` (n, k) and per row, from one array of squares."""
    if not x.size:
        return float("nan"), np.full(len(x), np.nan)
    row_means = np.square(x).mean(axis=1)
    return float(np.sqrt(row_means.mean())), np.sqrt(row_means)


def _max_abs(x: np.ndarray) -> float:
    """max |x| without an array of absolute values (NaN if empty)."""
    return float(max(x.max(), -x.min())) if x.size else float("nan")


def run_metrics(
    signals: Mapping[str, np.ndarray],
    roles: Roles,
    *,
    fs: float | None = None,
    windows: Mapping[str, tuple[float, float]] | None = None,
    detector: Detector = DEFAULT_DETECTOR,
) -> dict[str, float]:
    """:func:`base_metrics` of the whole run, then per named window (``<metric>@<name>``, needs
    ``fs``; NaN for a window the run ended before), and the detector's columns where the roles
    give input limits and ``fs`` is known."""
    out = base_metrics(signals, roles)
    if fs is None:
        return out
    k = int(out["n_samples"])
    for name, (t0, t1) in (windows or {}).items():
        lo, hi = _sample_index(t0, fs, k), _sample_index(t1, fs, k)
        part = {n: np.asarray(signals[n], dtype=float)[lo:hi] for n in _names(roles)} if hi > lo else None
        values = base_metrics(part, roles) if part is not None else dict.fromkeys(out, float("nan"))
        out.update({f"{key}@{name}": v for key, v in values.items()})
    if roles.input_limits and roles.inputs:
        lo, hi = np.array(roles.input_limits, dtype=float).T
        out.update(detector.detect(_stack(signals, roles.inputs, k), lo, hi, fs))
    return out


def _sample_index(t: float, fs: float, k: int) -> int:
    """First sample at or after ``t`` [s], at most ``k``: a window may end (or start) past the run,
    however far (``[2.5, 1e308]`` means "to the end"; ``t·fs`` may overflow to inf)."""
    x = t * fs - 1e-9
    return k if x >= k else math.ceil(x)


def _names(roles: Roles) -> tuple[str, ...]:
    return (*roles.errors, *roles.inputs, *roles.error_hats, *roles.currents)


def base_metrics(
    signals: Mapping[str, np.ndarray],
    roles: Roles,
) -> dict[str, float]:
    """Metrics of one run from its channels (each a (K,) array, one sample per tick).

    - ``rms_error`` = sqrt(mean over samples and outputs of e²) (thesis Sec. 3.4.1), and
      ``rms_e_<output>`` per controlled output (the plate's y1..y3);
    - ``rms_error_hat``: the same for ê (paper 2) where logged, with ``rms_e_hat_<output>``;
    - ``input_energy`` = Σ_j Σ_inputs u[j]² (thesis 3.5.1), per input ``energy_<input>`` when
      there are several; ``max_abs_input`` = max |u|;
    - ``max_current`` = max |i| over channels measured in ampere (NaN if none).

    Channels of unequal length (a torn log) are cut to the shortest.
    """
    lengths = {len(signals[name]) for name in _names(roles)}
    k = min(lengths) if lengths else 0
    out: dict[str, float] = {"n_samples": k}  # a count: an integer in the ledger, the log and the table
    for key, names in (("rms_error", roles.errors), ("rms_error_hat", roles.error_hats)):
        out[key], per_row = _rms_rows(_stack(signals, names, k))
        out.update({f"rms_{name}": float(v) for name, v in zip(names, per_row)})
    u = _stack(signals, roles.inputs, k)
    energy = np.sum(np.square(u), axis=1)
    out["input_energy"] = float(energy.sum()) if u.shape[0] else float("nan")
    if len(roles.inputs) > 1:
        for name, value in zip(roles.inputs, energy):
            out[f"energy_{name}"] = float(value)
    out["max_abs_input"] = _max_abs(u)
    out["max_current"] = _max_abs(u if roles.currents == roles.inputs else _stack(signals, roles.currents, k))
    return out
