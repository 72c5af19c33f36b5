"""The reference-law check of a device-loop run: does what the device logged follow the law?

The host recomputes the run from the device's own logged measurements y[k] (the engine's loop on
a :class:`~labrunner.rigs.device.replay.ReplayRig`: controller, reference and safety routine,
no plant) and compares every logged column — inputs u, controlled outputs, references,
estimates — and the verdict with what the device sent. The flag is ``ok``, ``diverged@tick K``
(the first tick where a column leaves its tolerance, or where the verdicts part) or
``not-checked`` (no samples to check).

**Tolerance.** The device computes from its float64 measurement y; the host sees y rounded to
float32 (≤ ½ ulp each), and every column it compares is float32 too. How far that rounding can
move a column is measured, not guessed: the law is run four times in one batch, on the logged
y, on y with ±1 float32 ulp of random sign added to every sample, and on y ± 1 ulp (twice the
rounding's worst case per sample: uncorrelated errors of a moving signal, and the errors all
alike of a signal at rest, which a long filter does not average away). A column's tolerance at
tick k is ``TOLERANCE_FACTOR`` × the largest spread of those runs from the logged y's run, from
tick 0 to the end of the ``BLOCK`` ticks after k's block (errors persist: the estimators sum
the applied inputs that carry them), plus 2 float32 ulp of the largest magnitude the column
reached up to k (a value near 0 is a cancellation of terms of that size: 1 + 4 − 5 summed in
another order is 8.9e−16). Columns the measurement does not reach (references, an open loop's
input) keep the 2 ulp. A firmware that
computes the law in float64, as the documents ask (docs/control-laws.md), passes with margin; a
law that differs by more than the rounding's effect is caught at its first tick.

**float32 devices** (IDENTITY capability FLOAT32): the law's own rounding in single precision is
added, bounded a priori by :mod:`~labrunner.rigs.device.f32bound` (the law of
:mod:`~labrunner.rigs.device.doclaw` run on numbers that carry their float32 error bound).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from labrunner import engine
from labrunner.control import factory
from labrunner.rigs.base import RigInfo
from labrunner.rigs.device import description, doclaw
from labrunner.rigs.device.columns import column_names
from labrunner.rigs.device.f32bound import Bounded
from labrunner.rigs.device.lawflag import DIVERGED, FLOAT32, FLOAT64, NOT_CHECKED, OK
from labrunner.rigs.device.replay import replay, stack_signals
from labrunner.rigs.transports.messages import Capability
from labrunner.safety import MONITORS

#: tolerance = this × the spread the float32 rounding of y causes, + 2 ulp (module docstring)
TOLERANCE_FACTOR = 4.0
F64_ULPS = 16.0  #: dither of an exact (float64) measurement: a device's own rounding in another order
BLOCK = 64  #: ticks per block of the spread's envelope (:func:`_envelope`)


@dataclass(frozen=True)
class LawCheck:
    """The check's result: ``flag`` (ok, diverged@tick K, not-checked) and the first divergence."""

    flag: str
    tick: int | None = None
    column: str | None = None
    device: float | None = None
    expected: float | None = None
    tolerance: float | None = None
    detail: str = ""
    worst_ratio: float = 0.0  # the largest |device − law| / tolerance over the checked ticks
    worst_at: str = ""  # its column and tick
    arithmetic: str = FLOAT64  # the tolerance's: float64, or float32 (the law's rounding bounded a priori)

    def as_dict(self) -> dict[str, object]:
        return asdict(self)

    @property
    def ok(self) -> bool:
        return self.flag == OK


def _ulp32(x: np.ndarray) -> np.ndarray:
    """One float32 ulp at each value (finite values; 0 elsewhere)."""
    finite = np.where(np.isfinite(x), x, 0.0)
    return np.spacing(np.abs(finite).astype(np.float32)).astype(float)


def check(
    point: Mapping[str, object],
    info: RigInfo,
    rows: np.ndarray,
    outcome: engine.Outcome,
    *,
    fs: float,
    duration: float,
    seed: int = 0,
    rig_safety: Mapping[str, object] | None = None,
    measured: np.ndarray | None = None,
    arithmetic: str = FLOAT64,
) -> LawCheck:
    """Check a device run of ``point``: its (n, columns) logged ``rows`` in block order and its
    ``outcome`` against the law recomputed from the rows' measurements — or, given the float64
    ``measured`` y the device read (a conformance vector's sensor table), from those: then the
    dithers are ±:data:`F64_ULPS` float64 ulp (another summation order's rounding), not float32's.
    ``arithmetic`` float32: the tolerance adds the a-priori bound of the law's float32 rounding."""
    rows = np.asarray(rows, float)
    if rows.ndim != 2 or rows.shape[0] == 0:
        return LawCheck(NOT_CHECKED, detail="the device logged no samples", arithmetic=arithmetic)
    names = column_names_of(point, info, fs)
    if measured is None:
        y = rows[:, [names.index(s.name) for s in info.outputs]]
        ulp = _ulp32(y)
    else:
        y = np.asarray(measured, float)
        ulp = F64_ULPS * np.spacing(np.abs(np.where(np.isfinite(y), y, 0.0)))
    signs = np.random.default_rng(0).choice([-1.0, 1.0], y.shape)
    tables = [y, y + signs * ulp, y + ulp, y - ulp]  # rounding errors uncorrelated, and all alike (a signal at rest)
    runs = replay(point, info, np.stack(tables), fs=fs, duration=duration, seed=seed, rig_safety=rig_safety)
    law = [stack_signals(r, names) for r in runs]
    n = min(rows.shape[0], *(len(x) for x in law))
    spread = np.zeros((n, len(names)))
    for other in law[1:]:
        diff = np.abs(other[:n] - law[0][:n])
        np.maximum(spread, np.where(np.isfinite(diff), diff, 0.0), out=spread)
    spread = _envelope(spread)
    expected = law[0][:n]
    scale = np.maximum.accumulate(np.fmax(np.abs(expected), np.abs(rows[:n])), axis=0)  # a value near 0 is a
    tolerance = TOLERANCE_FACTOR * spread + 2.0 * _ulp32(scale)  # cancellation of terms of the column's size
    if arithmetic == FLOAT32:
        tolerance += float32_bound(point, info, y, fs=fs, duration=duration, seed=seed, rig_safety=rig_safety)[:n]
    error = np.abs(rows[:n] - expected)
    both_nan = np.isnan(rows[:n]) & np.isnan(expected)
    bad = ~both_nan & ~(error <= tolerance)  # NaN on one side only counts as a divergence
    if (outcome.monitor or "") in NON_FINITE and rows.shape[0] <= n:
        bad[rows.shape[0] - 1, free_at_fault(names, info)] = False  # docs/control-laws.md, "A non-finite measurement"
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(bad | both_nan, 0.0, error / np.where(tolerance > 0, tolerance, np.inf))
    ratio[~np.isfinite(ratio)] = 0.0  # a tick whose estimates may be NaN (above)
    worst = float(np.max(ratio, initial=0.0))
    at = np.unravel_index(int(np.argmax(ratio)), ratio.shape) if ratio.size else (0, 0)
    where = f"{names[at[1]]} at tick {int(at[0])}" if worst > 0 else ""
    if bad.any():
        k, c = np.argwhere(bad)[0]
        return LawCheck(
            f"{DIVERGED}@tick {int(k)}", int(k), names[c], float(rows[k, c]), float(expected[k, c]),
            float(tolerance[k, c]),
            f"{names[c]} at tick {int(k)} (t = {k / fs:.6g} s): device {rows[k, c]:.9g}, law {expected[k, c]:.9g}, "
            f"tolerance {tolerance[k, c]:.3g} ({arithmetic})",
            worst, where, arithmetic,
        )  # fmt: skip
    base = (outcome.monitor or "").partition(":")[0]
    if outcome.status == "aborted" and base not in MONITORS:
        k = rows.shape[0] - 1
        detail = f"the device's monitor {outcome.monitor!r} is none of the safety routine's ({', '.join(MONITORS)})"
        return LawCheck(
            f"{DIVERGED}@tick {k}",
            k,
            "verdict",
            detail=detail,
            worst_ratio=worst,
            worst_at=where,
            arithmetic=arithmetic,
        )
    if outcome.status != "failed":  # a failed run (stopped, a link fault) has no verdict of the law's to match
        mine = (outcome.status, outcome.monitor or None, rows.shape[0])
        theirs = [(r.outcome.status, r.outcome.monitor, r.n_samples) for r in runs]
        if mine not in theirs:
            status, monitor, m = theirs[0]
            k = min(rows.shape[0], m) - 1
            return LawCheck(
                f"{DIVERGED}@tick {k}", k, "verdict", detail=(
                    f"the device ended {outcome.status}{_on(outcome.monitor)} after {rows.shape[0]} ticks, "
                    f"the law {status}{_on(monitor)} after {m}"
                ), worst_ratio=worst, worst_at=where, arithmetic=arithmetic,
            )  # fmt: skip
    detail = f"{n} ticks × {len(names)} columns within the {arithmetic} tolerance"
    return LawCheck(OK, detail=detail, worst_ratio=worst, worst_at=where, arithmetic=arithmetic)


def float32_bound(
    point: Mapping[str, object],
    info: RigInfo,
    y: np.ndarray,
    *,
    fs: float,
    duration: float,
    seed: int = 0,
    rig_safety: Mapping[str, object] | None = None,
) -> np.ndarray:
    """(ticks, columns): per tick and logged column, how far a float32 computation of the law on
    the measurements ``y`` can be from the float64 law (docs/control-laws.md, "float32 devices");
    past the bounded run's end, its last row."""
    data = description.build(point, info, fs=fs, duration=duration, seed=seed, rig_safety=rig_safety, sensor_table=y)
    names = ([s.name for s in info.inputs], [s.name for s in info.outputs])
    _, verdict = doclaw.run(description.decode(data), *names, dtype=Bounded)
    bounds = np.asarray(verdict["bounds"], float).reshape(-1, len(column_names_of(point, info, fs)))
    if len(bounds) == 0:
        return np.zeros((len(y), bounds.shape[1]))
    if len(bounds) < len(y):
        bounds = np.concatenate([bounds, np.repeat(bounds[-1:], len(y) - len(bounds), axis=0)])
    return bounds


NON_FINITE = ("non_finite_input", "non_finite_output")


def free_at_fault(names: list[str], info: RigInfo) -> list[int]:
    """The columns a tick with a non-finite measurement may log as NaN or as a number: the
    estimates and the controlled outputs not measured (a FIR may or may not multiply x[k] by a
    zero weight); its inputs, measured outputs and references are checked."""
    fixed = {s.name for s in (*info.inputs, *info.outputs)}
    return [j for j, name in enumerate(names) if name not in fixed and not name.startswith("ref_")]


def arithmetic_of(capabilities: int) -> str:
    """The arithmetic a device computes its laws in, from its IDENTITY capabilities (bit FLOAT32)."""
    return FLOAT32 if capabilities & Capability.FLOAT32 else FLOAT64


def column_names_of(point: Mapping[str, object], info: RigInfo, fs: float) -> list[str]:
    """The logged columns of ``point``'s device run (SAMPLES order)."""
    controller, _ = factory.build([point], info, fs)
    return column_names(engine.channel_names(info, controller))


def _envelope(spread: np.ndarray) -> np.ndarray:
    """Per tick k, the largest spread from tick 0 up to the end of the block of :data:`BLOCK`
    ticks after k's: rounding errors persist (the estimators sum the applied inputs, which carry
    them, over their whole window), and one dithered tick may be small by chance."""
    n, c = spread.shape
    blocks = -(-n // BLOCK)
    padded = np.zeros((blocks * BLOCK, c))
    padded[:n] = spread
    peak = np.maximum.accumulate(padded.reshape(blocks, BLOCK, c).max(axis=1), axis=0)
    peak[:-1] = peak[1:]  # the next block's too
    return np.repeat(peak, BLOCK, axis=0)[:n]


def _on(monitor: str | None) -> str:
    return f" ({monitor})" if monitor else ""
