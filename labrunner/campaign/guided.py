"""Guided campaigns: tuning procedures that choose their next runs from the outcomes so far.

A procedure is a *plan* in the Bluesky sense: a generator that yields :class:`Request`\\ s (a stage
name and the points it wants run, as parameter dicts of dotted keys) and is sent back one
:class:`Observation` per point. It touches no rig and no ledger, so its decisions are a pure
function of the outcomes: :func:`advance` drives a fresh plan with every outcome known so far and
returns either the points to run next (one *round*) or the plan's :class:`Result`. This module
imports nothing of the campaign but :mod:`~labrunner.campaign.grid` and
:mod:`~labrunner.campaign.expressions`: the round loop over the scheduler
(:mod:`labrunner.campaign.guided_run`) executes each round as ordinary ledger rows, so after a
crash the decision state is rebuilt from the ledger alone by replaying the plan.

A point asked for twice (e.g. the start of a second stage) is run once: outcomes are keyed by the
point's stable id, the same id a grid point would have. Procedures (``[guided] procedure = …``,
the table in :mod:`labrunner.campaign.procedures`):
``guideline2`` (thesis Guideline 2, Sec. 3.5.1, cases 1 and 2, walk or bisection), ``guideline3``
(Guideline 3, Sec. 3.5.2), ``polack`` (Polack et al. 2019 as thesis Sec. 3.5.3 applies it) —
:mod:`labrunner.campaign.guided_walks`; ``refine`` (stability-boundary refinement) —
:mod:`labrunner.campaign.guided_refine`.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from labrunner.campaign.grid import Axis, canonical_json, point_id
from labrunner.errors import InvalidParameter, check_finite


@dataclass(frozen=True)
class Observation:
    """The outcome of one run as a procedure sees it (from its ledger row)."""

    id: str
    params: Mapping[str, Any]
    status: str  # completed | aborted | no-motion | failed
    rms_error: float | None = None
    input_energy: float | None = None
    oscillating: bool = False  # completed, but the oscillation detector flagged it (labrunner.oscillation)

    @property
    def tripped(self) -> bool:
        """The safety routine aborted the run (thesis Sec. 3.3: the loop oscillated)."""
        return self.status == "aborted"

    @property
    def completed(self) -> bool:
        return self.status == "completed" and self.rms_error is not None and math.isfinite(self.rms_error)


@dataclass(frozen=True)
class Request:
    """Points a plan wants run before it decides again; ``stage`` names the step of the procedure."""

    stage: str
    points: tuple[Mapping[str, Any], ...]


@dataclass(frozen=True)
class Result:
    """How a plan ended: the chosen point (None if none qualifies) and why."""

    chosen: Observation | None
    reason: str
    detail: Mapping[str, Any] = field(default_factory=dict)  # procedure-specific (e.g. boundary cells)


Plan = Generator[Request, list[Observation], Result]


@dataclass(frozen=True)
class WalkStep:
    """One point of the walk in the order the plan asked for it; ``new``: first asked here."""

    stage: str
    observation: Observation
    new: bool


@dataclass(frozen=True)
class Advance:
    """A plan driven as far as the known outcomes allow."""

    next: tuple[Mapping[str, Any], ...]  # points to run now (empty when the plan has ended)
    stage: str  # the stage asking for them ("" when ended)
    result: Result | None
    walk: tuple[WalkStep, ...]

    def stage_counts(self) -> dict[str, dict[str, int]]:
        """Per stage (in order): steps (points it looked at) and runs (points first run there)."""
        out: dict[str, dict[str, int]] = {}
        for step in self.walk:
            entry = out.setdefault(step.stage, {"steps": 0, "runs": 0})
            entry["steps"] += 1
            entry["runs"] += int(step.new)
        return out

    @property
    def runs(self) -> int:
        return sum(step.new for step in self.walk)


class Procedure(ABC):
    """A guided procedure: its parameters (frozen dataclass fields) and its plan."""

    name: ClassVar[str]

    @abstractmethod
    def plan(self) -> Plan:
        """A fresh plan (generator); must depend only on the procedure's parameters and what it is sent."""

    @abstractmethod
    def max_runs(self) -> int:
        """An upper bound of the runs the plan can ask for (dry-run, progress)."""

    @abstractmethod
    def corners(self) -> list[dict[str, Any]]:
        """Extreme points of the search space, statically checked before anything is created."""

    def axes(self) -> tuple[tuple[Axis, ...], ...]:
        """Grid-like axis groups for the analysis maps (empty: no map, only the walk)."""
        return ()

    @abstractmethod
    def describe(self) -> str:
        """One line for ``--dry-run`` and reports."""

    def identity(self) -> str:
        """Canonical text of the parameters (part of the plan checksum)."""
        return canonical_json({"procedure": self.name, **dataclasses.asdict(self)})


def advance(procedure: Procedure, campaign: str, known: Mapping[str, Observation]) -> Advance:
    """Drive a fresh plan with the outcomes ``known`` (point id → observation) of campaign ``campaign``.

    Returns the first request with a point whose outcome is unknown (its unknown points, in order,
    without repeats) or the plan's result. Pure: equal ``known`` give equal answers."""
    plan = procedure.plan()
    walk: list[WalkStep] = []
    seen: set[str] = set()
    try:
        request = next(plan)
        while True:
            ids = [point_id(campaign, p) for p in request.points]
            missing: dict[str, Mapping[str, Any]] = {i: p for i, p in zip(ids, request.points) if i not in known}
            if missing:
                plan.close()
                return Advance(tuple(missing.values()), request.stage, None, tuple(walk))
            answers = [known[i] for i in ids]
            for i, obs in zip(ids, answers):
                walk.append(WalkStep(request.stage, obs, i not in seen))
                seen.add(i)
            request = plan.send(answers)
    except StopIteration as stop:
        return Advance((), "", stop.value, tuple(walk))


def ask(stage: str, *points: Mapping[str, Any]) -> Request:
    return Request(stage, tuple(points))


def best(observations: Sequence[Observation]) -> Observation | None:
    """The completed run with the smallest RMS error (the thesis's quality gauge, Sec. 3.5.1)."""
    done = [o for o in observations if o.completed]
    return min(done, key=lambda o: o.rms_error) if done else None


@dataclass(frozen=True)
class Ladder:
    """Log-spaced values from ``start`` towards ``stop`` (either direction), ``per_decade`` per decade.

    Thesis Sec. 3.5.3 samples 16 per decade: Guideline 2 goes from γ̃ = 10⁶ to 421.69 = 10^2.625 in
    54 steps, Polack's feedback stage from k_p = 0.1 to 31.62 = 10^1.5 in 40. Value i is
    10^(log10 start ± i/per_decade) rounded to 12 significant digits, so that a last-bit difference
    of another machine's ``pow`` does not change a point's id (a resume elsewhere replays the same points)."""

    start: float
    stop: float
    per_decade: int

    def values(self) -> tuple[float, ...]:
        e0, e1 = math.log10(self.start), math.log10(self.stop)
        h = math.copysign(1.0 / self.per_decade, e1 - e0)
        n = math.floor(abs(e1 - e0) * self.per_decade + 1e-9) + 1
        return tuple(float(f"{10.0 ** (e0 + i * h):.12g}") for i in range(n))


REQUIRED = _REQUIRED = object()  # a default meaning "the key must be given"


class Table:
    """Reads ``[guided]`` key by key; every error names ``guided.<key>``; :meth:`done` rejects the rest."""

    def __init__(self, table: Mapping[str, Any], names: Mapping[str, float]) -> None:
        self.table, self.names = dict(table), names
        self.used = {"procedure"}

    def _get(self, key: str, default: Any) -> Any:
        self.used.add(key)
        if key not in self.table:
            if default is _REQUIRED:
                raise InvalidParameter(f"guided.{key}", "is required")
            return default
        return self.table[key]

    def number(
        self, key: str, default: Any = None, *, lo: float | None = None, lo_open: bool = True, hi: float | None = None
    ) -> float | None:
        """A number, or an expression over the rig's constants (``rho = "b"``), within (lo, hi]."""
        value = self._get(key, default)
        if value is None:
            return None
        if isinstance(value, str):
            from labrunner.campaign import expressions

            value = expressions.parse(f"guided.{key}", value, set(self.names)).evaluate(self.names)
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InvalidParameter(f"guided.{key}", f"must be a number, got {value!r}")
        v = check_finite(f"guided.{key}", value)
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise InvalidParameter(f"guided.{key}", f"must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            raise InvalidParameter(f"guided.{key}", f"must be <= {hi:g}, got {v:g}")
        return v

    def integer(self, key: str, default: Any, lo: int, hi: int) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise InvalidParameter(f"guided.{key}", f"must be an integer in [{lo}, {hi}], got {value!r}")
        return value

    def choice(self, key: str, default: Any, allowed: Sequence[Any]) -> Any:
        value = self._get(key, default)
        if value not in allowed:
            raise InvalidParameter(f"guided.{key}", f"must be one of {', '.join(map(str, allowed))}, got {value!r}")
        return value

    def raw(self, key: str, default: Any = None) -> Any:
        return self._get(key, default)

    def done(self) -> None:
        unknown = sorted(set(self.table) - self.used)
        if unknown:
            raise InvalidParameter(f"guided.{unknown[0]}", f"unknown key; allowed: {', '.join(sorted(self.used))}")


Oracle = Callable[[list[Mapping[str, Any]]], list[Mapping[str, Any]]]


def drive(
    procedure: Procedure, campaign: str, oracle: Oracle, known: Mapping[str, Observation] | None = None
) -> Advance:
    """Run a plan to its end in-process: ``oracle(points)`` gives each point's outcome as a mapping
    with ``status`` (and ``rms_error``, ``input_energy``). For tests (a fake plant) and for quick
    studies with :func:`labrunner.campaign.guided_run.engine_oracle`; campaigns go through the ledger instead."""
    outcomes = dict(known or {})
    while True:
        step = advance(procedure, campaign, outcomes)
        if step.result is not None:
            return step
        for point, out in zip(step.next, oracle(list(step.next)), strict=True):
            pid = point_id(campaign, point)
            outcomes[pid] = Observation(
                pid,
                dict(point),
                str(out["status"]),
                out.get("rms_error"),
                out.get("input_energy"),
                out.get("oscillating") == 1.0,
            )
