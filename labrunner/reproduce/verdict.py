"""What a check of ``labrunner reproduce`` returns, and the measurements several checks share.

A :class:`Verdict` is one of three kinds: the twin **agrees** with the claim, it **disagrees**, or
the claim is **not testable on the twin** (``agrees`` None, with the reason in ``measured``) — for
example a measurement the twin was calibrated on, or a figure whose data the source does not print.
A claim with several parts lists each in :class:`Part`; the verdict agrees only if every testable
part does. Pure functions of the metrics tables; "observed unstable" is aborted or oscillating
(:func:`labrunner.analysis.agreement.observed_outcome`), as in the maps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from labrunner.analysis.agreement import observed_outcome
from labrunner.reproduce.run import CampaignResult

Results = Mapping[str, CampaignResult]
#: How a verdict reads in the report and the JSON summary.
KINDS = {True: "agrees", False: "disagrees", None: "not testable"}


@dataclass(frozen=True)
class Part:
    """One part of a claim: what it says, what the twin gave, whether they agree (None: not testable)."""

    claim: str
    measured: str
    agrees: bool | None

    def line(self) -> str:
        mark = {True: "agrees", False: "DISAGREES", None: "not testable"}[self.agrees]
        return f"{self.claim} — measured: {self.measured} [{mark}]"


@dataclass(frozen=True)
class Verdict:
    measured: str
    agrees: bool | None  # a plain bool (numpy's comparisons are converted); None: not testable on the twin
    table: pd.DataFrame | None = None

    def __post_init__(self) -> None:
        if self.agrees is not None:
            object.__setattr__(self, "agrees", bool(self.agrees))

    @property
    def kind(self) -> str:
        return KINDS[self.agrees]


def combine(parts: Sequence[Part], table: pd.DataFrame | None = None, note: str = "") -> Verdict:
    """The verdict of a claim made of ``parts``: disagrees if any testable part does, agrees if every
    testable part does, not testable if none is."""
    testable = [p.agrees for p in parts if p.agrees is not None]
    agrees = None if not testable else all(testable)
    text = "; ".join(f"({i}) {p.line()}" for i, p in enumerate(parts, 1))
    return Verdict(text + (f". {note}" if note else ""), agrees, table)


def not_testable(reason: str, table: pd.DataFrame | None = None) -> Verdict:
    return Verdict(f"not testable on the twin: {reason}", None, table)


def one(results: Results, part: str = "") -> CampaignResult:
    """The result whose file name contains ``part`` (the first one for "")."""
    return next(r for f, r in results.items() if part in Path(f).name)


def unstable(frame: pd.DataFrame) -> pd.Series:
    return observed_outcome(frame).isin(("aborted", "oscillating"))


def done(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[observed_outcome(frame) == "completed"]


def fs_of(run: CampaignResult) -> float:
    from labrunner.campaign import runner, spec

    return float(spec.load(run.directory / runner.CAMPAIGN_COPY).fs)


def predictions(run: CampaignResult, family: str) -> pd.DataFrame:
    """Per row of ``run``: the prediction of its controller's ``family`` case ("motor": thesis (2.46) or
    (2.58)–(2.59); "ultralocal": (2.41) or (2.53)–(2.54)) as columns ``predicted_stable`` (NaN where the
    case does not apply) and ``bound_distance``, and ``observed`` (observed_outcome)."""
    from labrunner.analysis.context import Theories
    from labrunner.campaign import runner, spec

    campaign = spec.load(run.directory / runner.CAMPAIGN_COPY, root=spec.project_root(Path(run.file)))
    theories = Theories(campaign)
    frame = run.frame
    stable, distance = [], []
    for row in frame[[c for c in frame.columns if "." in c]].to_dict("records"):
        theory = theories(row)
        case = next((c for c in (theory.cases() if theory else []) if c.endswith(family)), None)
        if case is None:
            stable.append(math.nan)
            distance.append(math.nan)
            continue
        s, d = theory.predict(case, theories.gains(row))
        stable.append(float(s))
        distance.append(d)
    return frame.assign(predicted_stable=stable, bound_distance=distance, observed=observed_outcome(frame))


def grid_index(frame: pd.DataFrame, axes: Sequence[str]) -> np.ndarray:
    """(rows, len(axes)) integer positions of each row on each axis (rank among the axis's values)."""
    return np.stack([np.searchsorted(np.unique(frame[a]), frame[a]) for a in axes], axis=1)


def at_boundary(frame: pd.DataFrame, axes: Sequence[str], predicted: str = "predicted_stable") -> np.ndarray:
    """Per row: whether a grid neighbour (one step along one axis) has the other predicted class —
    the row lies next to the predicted boundary, where the grid cannot place the boundary closer."""
    index = grid_index(frame, axes)
    cls = dict(zip(map(tuple, index), frame[predicted]))
    out = np.zeros(len(frame), dtype=bool)
    for r, (pos, c) in enumerate(zip(map(tuple, index), frame[predicted])):
        for axis in range(len(axes)):
            for step in (-1, 1):
                n = list(pos)
                n[axis] += step
                other = cls.get(tuple(n))
                if other is not None and not (isinstance(other, float) and math.isnan(other)) and other != c:
                    out[r] = True
    return out


def bound_parts(
    run: CampaignResult, family: str, label: str, where: pd.Series | None = None
) -> tuple[Part, pd.DataFrame]:
    """Does the ``family`` bound place the observed stability boundary to within one grid step?

    Compared: completed/no-motion (stable) and aborted/oscillating (unstable) runs, restricted to
    ``where``. A run whose observed class differs from the prediction counts against the bound unless
    a grid neighbour is predicted in the other class (the boundary passes between them)."""
    frame = predictions(run, family)
    axes = [
        c for c in ("controller.gamma", "controller.k_p", "controller.k_d") if c in frame and frame[c].nunique() > 1
    ]
    frame = frame.assign(at_boundary=at_boundary(frame, axes))
    frame = frame[frame["predicted_stable"].notna() & frame["observed"].isin(_CLASSES)]
    if where is not None:
        frame = frame[where.reindex(frame.index, fill_value=False)]
    obs_stable = frame["observed"].isin(("completed", "no-motion"))
    wrong = obs_stable != frame["predicted_stable"].astype(bool)
    far = wrong & ~frame["at_boundary"]
    n = len(frame)
    measured = (
        f"{n - int(wrong.sum())} of {n} points as predicted; {int(wrong.sum())} not, {int(far.sum())} of them more "
        f"than one grid step from the predicted boundary ({int((far & obs_stable).sum())} stable where predicted "
        f"unstable, {int((far & ~obs_stable).sum())} unstable where predicted stable)"
    )
    return Part(label, measured, None if n == 0 else not far.any()), frame.assign(mismatch=wrong, far=far)


_CLASSES = ("completed", "no-motion", "aborted", "oscillating")


def spread(values: np.ndarray) -> float:
    """max/min − 1 of positive values (NaN for fewer than two)."""
    return float(values.max() / values.min() - 1.0) if len(values) > 1 else math.nan
