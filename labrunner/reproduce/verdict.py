"""What a check of ``labrunner reproduce`` returns, and the measurements several checks share.

A :class:`Verdict` is one of four kinds: the twin **agrees** with the claim, it **disagrees**, the
runs cannot **decide** it (``undecided``: e.g. a detector rule on runs too short for it), or the
claim is **not testable on the twin** (``agrees`` None, with the reason in ``measured``) — for
example a measurement the twin was calibrated on, or a figure whose data the source does not print.
A claim with several parts lists each in :class:`Part`; the verdict agrees only if every testable
part does. :func:`judge` sets a verdict beside the same check's verdict on the item's falsification
variant (:class:`labrunner.reproduce.items.Variant`): a check that agrees on both is **not
discriminating**. Pure functions of the metrics tables; "observed unstable" is aborted or
oscillating (:func:`labrunner.analysis.agreement.observed_outcome`), as in the maps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd

from labrunner.analysis.agreement import observed_outcome
from labrunner.reproduce.run import CampaignResult

Results = Mapping[str, CampaignResult]
#: A check's references (the source's numbers it judges against), replaced by a variant's; empty: the source's.
Ref = Mapping[str, Any]
NO_REF: Ref = MappingProxyType({})
#: Every kind an item's verdict can take, in the order the report counts them.
KINDS = ("agrees", "disagrees", "not discriminating", "undecided", "not testable", "not reproduced")
_KIND = {True: "agrees", False: "disagrees", None: "not testable"}


@dataclass(frozen=True)
class Part:
    """One part of a claim: what it says, what the twin gave, whether they agree (None: not testable,
    or undecided when ``undecided`` gives the reason the runs cannot decide it)."""

    claim: str
    measured: str
    agrees: bool | None
    undecided: str = ""

    def line(self) -> str:
        mark = f"undecided: {self.undecided}" if self.undecided else _MARK[self.agrees]
        return f"{self.claim} — measured: {self.measured} [{mark}]"


_MARK = {True: "agrees", False: "DISAGREES", None: "not testable"}


@dataclass(frozen=True)
class Verdict:
    measured: str
    agrees: bool | None  # a plain bool (numpy's comparisons are converted); None: not testable or undecided
    table: pd.DataFrame | None = None
    undecided: bool = False  # agrees is None because the runs cannot decide a testable part

    def __post_init__(self) -> None:
        if self.agrees is not None:
            object.__setattr__(self, "agrees", bool(self.agrees))

    @property
    def kind(self) -> str:
        return "undecided" if self.undecided else _KIND[self.agrees]


def combine(parts: Sequence[Part], table: pd.DataFrame | None = None, note: str = "") -> Verdict:
    """The verdict of a claim made of ``parts``: disagrees if any testable part does, else undecided if
    any part is, agrees if every testable part does, not testable if none is."""
    testable = [p.agrees for p in parts if p.agrees is not None]
    undecided = any(p.undecided for p in parts) and all(testable)
    agrees = None if not testable or undecided else all(testable)
    text = "; ".join(f"({i}) {p.line()}" for i, p in enumerate(parts, 1))
    return Verdict(text + (f". {note}" if note else ""), agrees, table, undecided)


@dataclass(frozen=True)
class Judged:
    """An item's verdict on the twin beside the same check's verdict on its falsification variant."""

    twin: Verdict
    variant: Verdict | None  # None: the item declares none (then its check is not shown to discriminate)

    @property
    def kind(self) -> str:
        """The twin's kind, except that a check that agrees on the twin and on the variant, or agrees
        on the variant where it disagrees on the twin, cannot tell them apart: not discriminating."""
        twin = self.twin.kind
        if twin not in ("agrees", "disagrees"):
            return twin
        if (
            self.variant is None
            or self.variant.kind == "agrees"
            or (twin == "agrees" and self.variant.kind != "disagrees")
        ):
            return "not discriminating"
        return twin


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


def predictions(run: CampaignResult, family: str, bound: Mapping[str, float] | None = None) -> pd.DataFrame:
    """Per row of ``run``: the prediction of its controller's ``family`` case ("motor": thesis (2.46) or
    (2.58)–(2.59); "ultralocal": (2.41) or (2.53)–(2.54)) as columns ``predicted_stable`` (NaN where the
    case does not apply) and ``bound_distance``, and ``observed`` (observed_outcome). ``bound`` scales
    the theory's constants ("a", "b", "rho") or its delay ("delay") by the given factors: a
    deliberately wrong bound for a falsification variant."""
    from labrunner.analysis.context import Theories
    from labrunner.campaign import runner, spec

    campaign = spec.load(run.directory / runner.CAMPAIGN_COPY, root=spec.project_root(Path(run.file)))
    theories = Theories(campaign)
    frame = run.frame
    stable, distance = [], []
    for row in frame[[c for c in frame.columns if "." in c]].to_dict("records"):
        theory = _scaled(theories(row), bound or {})
        case = next((c for c in (theory.cases() if theory else []) if c.endswith(family)), None)
        if case is None:
            stable.append(math.nan)
            distance.append(math.nan)
            continue
        s, d = theory.predict(case, theories.gains(row))
        stable.append(float(s))
        distance.append(d)
    return frame.assign(predicted_stable=stable, bound_distance=distance, observed=observed_outcome(frame))


def _scaled(theory: Any, factors: Mapping[str, float]) -> Any:
    """``theory`` with its constants and delay scaled by ``factors`` (itself when there are none)."""
    if theory is None or not factors:
        return theory
    constants = {k: v * factors.get(k, 1.0) if k in ("a", "b", "rho") else v for k, v in theory.constants.items()}
    return replace(theory, constants=constants, delay=theory.delay * factors.get("delay", 1.0))


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
    run: CampaignResult,
    family: str,
    label: str,
    where: pd.Series | None = None,
    bound: Mapping[str, float] | None = None,
) -> tuple[Part, pd.DataFrame]:
    """Does the ``family`` bound (scaled by ``bound``, see :func:`predictions`) place the observed
    stability boundary to within one grid step?

    Compared: completed/no-motion (stable) and aborted/oscillating (unstable) runs, restricted to
    ``where``. A run whose observed class differs from the prediction counts against the bound unless
    a grid neighbour is predicted in the other class (the boundary passes between them). A selection
    without points more than a grid step on both sides of the bound cannot confirm it (not testable)
    unless a point already contradicts it."""
    frame = predictions(run, family, bound)
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
    predicted = frame["predicted_stable"].astype(bool)
    missing = [
        side for side, s in (("inside", predicted), ("beyond", ~predicted)) if not (s & ~frame["at_boundary"]).any()
    ]
    measured = (
        f"{n - int(wrong.sum())} of {n} points as predicted; {int(wrong.sum())} not, {int(far.sum())} of them more "
        f"than one grid step from the predicted boundary ({int((far & obs_stable).sum())} stable where predicted "
        f"unstable, {int((far & ~obs_stable).sum())} unstable where predicted stable)"
    )
    if missing and n and not far.any():
        measured += f"; no point lies more than a grid step {' or '.join(missing)} the bound, so it cannot place it"
    agrees = False if far.any() else None if n == 0 or missing else True
    return Part(label, measured, agrees), frame.assign(mismatch=wrong, far=far)


_CLASSES = ("completed", "no-motion", "aborted", "oscillating")


def spread(values: np.ndarray) -> float:
    """max/min − 1 of positive values (NaN for fewer than two)."""
    return float(values.max() / values.min() - 1.0) if len(values) > 1 else math.nan
