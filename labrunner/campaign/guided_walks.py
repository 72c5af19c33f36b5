"""The thesis's tuning procedures as guided plans: Guideline 2 and 3 and Polack et al.'s two stages.

All three walk ladders of log-spaced gains (:class:`~labrunner.campaign.guided.Ladder`, 16 per
decade as in thesis Sec. 3.5.3) and stop by the rules the thesis states:

- **Guideline 2** (thesis Sec. 3.5.1, first-order MFC (3.6)), case 1: start at a large γ̃ and a small
  k̃_p, keep k_p(γ) = k̃_p γ̃ / γ (3.7) and decrease γ "until either the controlled system starts
  oscillating or the tracking error is appropriately small" — here: until the safety routine trips
  (thesis Sec. 3.3), a completed run oscillates (the oscillation detector's flag) or RMS(e) ≤
  ``rms_target``. Case 2 (ρ known): γ̃ = κρ, k̃_p = πκ/(2δ_t) (the
  conservative bound of appendix A.1), γ ∈ [ρ, κρ]. ``method = "bisect"`` finds the same first
  stopping point in O(log n) runs (Sec. 3.5.3: "the bisection method can be used to speed up the
  sampling"), assuming the stopping condition is monotone along the line (it stops at trips and the
  target only).
- **Guideline 3** (Sec. 3.5.2, second-order MFC (3.10)): γ = ρ; start at the highest k̃_p of the
  ultra-local stability set (appendix A.4) and its k̃_d; increase k_d until the boundary (a trip),
  "reduce it such that no oscillations occur" (default: the largest k_d below the trip whose run the
  detector does not flag; ``kd_back_off = n``: n rungs below the trip); then increase k_p until a
  trip, an oscillation or the RMS target.
- **Polack et al. (2019)** (Sec. 3.5.3): feed-forward stage, k_p = 0 (3.11), decrease γ from a large
  value until the loop trips, keep the γ with the smallest error — with the thesis's back-off
  (Fig. 3.22, the default ``back_off = "oscillation"``): the smallest-error γ whose run the
  oscillation detector does not flag (the thesis passed over 64.93 for 74.98 because the former
  oscillated as Ω_r returned to zero); ``back_off = n`` instead takes n rungs above the smallest-error
  γ whatever its runs did. Feedback stage: increase k_p from a small value until the error is small
  enough (or the loop trips).

A safety trip that ends a walk is the "starts oscillating" of the guidelines: the chosen point is
then the completed run with the smallest RMS error so far (Fig. 3.11: the best runs lie at the
edge of the stability boundary).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from labrunner.campaign.grid import Axis
from labrunner.campaign.guided import REQUIRED, Ladder, Observation, Plan, Procedure, Result, Table, ask, best
from labrunner.errors import InvalidParameter

GAMMA, KP, KD = "controller.gamma", "controller.k_p", "controller.k_d"


@dataclass(frozen=True)
class StageEnd:
    """How one walk ended: the runs it looked at (in order), why it stopped, its chosen run."""

    stage: str
    seen: tuple[Observation, ...]
    reason: str  # tripped | target | rising | end of range | failed | start trips
    chosen: Observation | None


def walk(
    stage: str,
    points: list[dict[str, Any]],
    *,
    target: float | None = None,
    patience: int | None = None,
    oscillation: bool = False,
):
    """Run ``points`` one by one until a trip, RMS(e) ≤ ``target``, ``patience`` rises of the RMS in a
    row, a failed run, the end of the ladder, or — with ``oscillation`` — a completed run the
    oscillation detector flags (the guidelines' "until the controlled system starts oscillating"; the
    choice is then the best run before it). A sub-plan; ``yield from`` it."""
    seen: list[Observation] = []
    rises = 0
    for point in points:
        (obs,) = yield ask(stage, point)
        prev = next((o for o in reversed(seen) if o.completed), None)
        seen.append(obs)
        if obs.status == "failed":
            return StageEnd(stage, tuple(seen), "failed", None)
        if obs.tripped:
            return StageEnd(stage, tuple(seen), "tripped", best(seen))
        if oscillation and obs.completed and obs.oscillating:
            return StageEnd(stage, tuple(seen), "oscillating", best([o for o in seen if not o.oscillating]))
        if target is not None and obs.completed and obs.rms_error <= target:
            return StageEnd(stage, tuple(seen), "target", obs)
        if patience is not None and obs.completed and prev is not None:
            rises = rises + 1 if obs.rms_error > prev.rms_error else 0
            if rises >= patience:
                return StageEnd(stage, tuple(seen), "rising", best(seen))
    return StageEnd(stage, tuple(seen), "end of range", best(seen))


def bisect(stage: str, points: list[dict[str, Any]], *, target: float | None = None):
    """The first point of ``points`` where a walk would stop, by bisection (a sub-plan).

    Stop condition S(i): a trip, or RMS ≤ ``target``; assumed monotone in i. Runs i = 0 and the last
    point, then halves [lo, hi] with S(lo) false, S(hi) true. Chosen: the stopping point if it met
    the target, else the last point before the first trip (the edge of the stable set)."""
    seen: dict[int, Observation] = {}

    def stops(obs: Observation) -> bool:
        return obs.tripped or (target is not None and obs.completed and obs.rms_error <= target)

    def end(reason: str, chosen: Observation | None) -> StageEnd:
        return StageEnd(stage, tuple(seen.values()), reason, chosen)

    last = len(points) - 1
    for i in dict.fromkeys((0, last)):  # the two ends (one point when the ladder has one)
        (seen[i],) = yield ask(stage, points[i])
        if seen[i].status == "failed":
            return end("failed", None)
        if i == 0 and stops(seen[0]):
            return end("start trips", None) if seen[0].tripped else end("target", seen[0])
    if not stops(seen[last]):
        return end("end of range", best(list(seen.values())))
    lo, hi = 0, last
    while hi - lo > 1:
        mid = (lo + hi) // 2
        (seen[mid],) = yield ask(stage, points[mid])
        if seen[mid].status == "failed":
            return end("failed", None)
        lo, hi = (lo, mid) if stops(seen[mid]) else (mid, hi)
    if not seen[hi].tripped:
        return end("target", seen[hi])
    edge = seen[lo] if seen[lo].completed else best(list(seen.values()))
    return end("tripped", edge)


def _stages(*ends: StageEnd) -> dict[str, Any]:
    return {
        "stages": [{"stage": e.stage, "reason": e.reason, "chosen": e.chosen.id if e.chosen else None} for e in ends]
    }


def loop_delay(campaign: Any) -> float:
    """δ [s] of the loop: the differentiator's estimation delay δ_t (thesis (2.3)) plus the rig's
    ``sensor_delay``, as the analysis overlays use it."""
    from labrunner.control import factory

    config = campaign.resolve({})
    try:
        design = factory.differentiators([config], float(campaign.fs), 0)[0]
    except (InvalidParameter, KeyError, IndexError) as exc:
        raise InvalidParameter(
            "guided.delay", f"cannot derive δ_t from [differentiator] ({exc}); give delay [s]"
        ) from None
    return design.delay_s + float(campaign.rig_info.constants.get("sensor_delay", 0.0))


def _check_kind(campaign: Any, kinds: tuple[str, ...], procedure: str) -> None:
    kind = campaign.base.get("controller", {}).get("kind")
    if kind not in kinds:
        raise InvalidParameter("controller.kind", f"procedure {procedure} tunes {' or '.join(kinds)}, got {kind!r}")


def _ladder(key: str, start: float, stop: float, per_decade: int, down: bool) -> tuple[float, ...]:
    """The ladder from ``start`` to ``stop``; ``guided.<key>`` (the stop) must lie on the right side."""
    if (stop >= start) if down else (stop <= start):
        raise InvalidParameter(f"guided.{key}", f"must be {'<' if down else '>'} the start {start:.6g}, got {stop:.6g}")
    return Ladder(start, stop, per_decade).values()


@dataclass(frozen=True)
class Guideline2(Procedure):
    """Guideline 2 (thesis Sec. 3.5.1): walk (or bisect) down γ along k_p(γ) = k̃_p γ̃ / γ."""

    name = "guideline2"
    case: int
    method: str
    gamma_start: float  # γ̃ (case 2: κρ)
    kp_start: float  # k̃_p (case 2: πκ/(2δ))
    gamma_stop: float  # lowest γ (case 2: ρ)
    per_decade: int
    rms_target: float | None

    @classmethod
    def from_table(cls, t: Table, campaign: Any) -> Guideline2:
        _check_kind(campaign, ("mfc1",), cls.name)
        case = t.choice("case", 1, (1, 2))
        method = t.choice("method", "walk", ("walk", "bisect"))
        per_decade = t.integer("per_decade", 16, 1, 1000)
        target = t.number("rms_target", None, lo=0.0)
        if case == 1:
            g0 = t.number("gamma_start", REQUIRED, lo=0.0)
            k0 = t.number("kp_start", 1.0, lo=0.0)  # Step 1: "e.g. k̃_p = 1 s⁻¹"
            g1 = t.number("gamma_stop", REQUIRED, lo=0.0)
        else:
            rho = t.number("rho", REQUIRED, lo=0.0)
            kappa = t.number("kappa", REQUIRED, lo=1.0)
            delay = t.number("delay", None, lo=0.0)
            delay = loop_delay(campaign) if delay is None else delay
            g0, k0, g1 = kappa * rho, math.pi * kappa / (2.0 * delay), rho  # case 2, Step 1
        _ladder("gamma_stop", g0, g1, per_decade, True)
        return cls(case, method, g0, k0, g1, per_decade, target)

    def line(self) -> list[dict[str, Any]]:
        """The points of (3.7), γ from γ̃ down to the stop."""
        c = self.kp_start * self.gamma_start
        return [{GAMMA: g, KP: c / g} for g in Ladder(self.gamma_start, self.gamma_stop, self.per_decade).values()]

    def plan(self) -> Plan:
        label = f"k_p = {self.kp_start * self.gamma_start:.6g}/γ"
        if self.method == "bisect":
            end = yield from bisect(label, self.line(), target=self.rms_target)
        else:  # Step 3: "until either the controlled system starts oscillating or the tracking error is ... small"
            end = yield from walk(label, self.line(), target=self.rms_target, oscillation=True)
        return Result(end.chosen, end.reason, _stages(end))

    def max_runs(self) -> int:
        n = len(self.line())
        return n if self.method == "walk" else min(n, 2 + math.ceil(math.log2(max(n - 1, 1))))

    def corners(self) -> list[dict[str, Any]]:
        line = self.line()
        return [line[0], line[-1]]

    def axes(self) -> tuple[tuple[Axis, ...], ...]:
        line = self.line()
        return ((Axis(GAMMA, tuple(p[GAMMA] for p in line), "log10"), Axis(KP, tuple(p[KP] for p in line), "log10")),)

    def describe(self) -> str:
        stop = f"a trip or RMS(e) ≤ {self.rms_target:g}" if self.rms_target is not None else "a trip"
        return (
            f"Guideline 2 case {self.case} ({self.method}): γ {self.gamma_start:.6g} → {self.gamma_stop:.6g}, "
            f"k_p = {self.kp_start:.6g}·{self.gamma_start:.6g}/γ, {self.per_decade}/decade, until {stop}"
        )


@dataclass(frozen=True)
class Polack(Procedure):
    """Polack et al. (2019) as thesis Sec. 3.5.3 applies it: feed-forward stage, then feedback stage."""

    name = "polack"
    gamma_start: float
    gamma_stop: float
    kp_start: float
    kp_stop: float
    per_decade: int
    back_off: int | None  # None: the thesis's rule (best γ not flagged oscillating); n: n rungs above the best γ
    rms_target: float | None
    patience: int | None

    @classmethod
    def from_table(cls, t: Table, campaign: Any) -> Polack:
        _check_kind(campaign, ("mfc1",), cls.name)
        per_decade = t.integer("per_decade", 16, 1, 1000)
        g0, g1 = t.number("gamma_start", REQUIRED, lo=0.0), t.number("gamma_stop", REQUIRED, lo=0.0)
        k0, k1 = t.number("kp_start", 0.1, lo=0.0), t.number("kp_stop", REQUIRED, lo=0.0)
        _ladder("gamma_stop", g0, g1, per_decade, True)
        _ladder("kp_stop", k0, k1, per_decade, False)
        back_off = None if t.raw("back_off") in (None, "oscillation") else t.integer("back_off", 0, 0, 100)
        target = t.number("rms_target", None, lo=0.0)
        patience = t.raw("patience")
        if patience is not None:
            patience = t.integer("patience", None, 1, 1000)
        return cls(g0, g1, k0, k1, per_decade, back_off, target, patience)

    def gammas(self) -> tuple[float, ...]:
        return Ladder(self.gamma_start, self.gamma_stop, self.per_decade).values()

    def gains(self) -> tuple[float, ...]:
        return Ladder(self.kp_start, self.kp_stop, self.per_decade).values()

    def plan(self) -> Plan:
        gammas = self.gammas()
        ff = yield from walk("feed-forward (k_p = 0)", [{GAMMA: g, KP: 0.0} for g in gammas])
        if ff.chosen is None:
            return Result(None, f"feed-forward stage: {ff.reason}, no completed run", _stages(ff))
        if self.back_off is None:  # thesis Fig. 3.22: pass over a best γ whose run oscillates
            calm = [o for o in ff.seen if o.completed and not o.oscillating]
            gamma = min(calm, key=lambda o: o.rms_error).params[GAMMA] if calm else ff.chosen.params[GAMMA]
        else:
            gamma = gammas[max(0, gammas.index(ff.chosen.params[GAMMA]) - self.back_off)]
        fb = yield from walk(
            f"feedback (γ = {gamma:.5g})",
            [{GAMMA: gamma, KP: k} for k in self.gains()],
            target=self.rms_target,
            patience=self.patience,
        )
        return Result(fb.chosen, fb.reason, {**_stages(ff, fb), "gamma": gamma})

    def max_runs(self) -> int:
        return len(self.gammas()) + len(self.gains())

    def corners(self) -> list[dict[str, Any]]:
        g, k = self.gammas(), self.gains()
        return [{GAMMA: g[0], KP: 0.0}, {GAMMA: g[-1], KP: 0.0}, {GAMMA: g[-1], KP: k[-1]}, {GAMMA: g[0], KP: k[0]}]

    def describe(self) -> str:
        stop = f"RMS(e) ≤ {self.rms_target:g}, " if self.rms_target is not None else ""
        return (
            f"Polack et al.: feed-forward k_p = 0, γ {self.gamma_start:.6g} → {self.gamma_stop:.6g} until a trip; "
            f"feedback k_p {self.kp_start:.6g} → {self.kp_stop:.6g} until {stop}a trip, {self.per_decade}/decade"
        )


@dataclass(frozen=True)
class Guideline3(Procedure):
    """Guideline 3 (thesis Sec. 3.5.2): γ = ρ, start at appendix A.4's highest k_p, raise k_d, then k_p."""

    name = "guideline3"
    rho: float
    kp_start: float  # k̃_p (Step 2)
    kd_start: float  # k̃_d (Step 2)
    kd_stop: float
    kp_stop: float
    per_decade: int
    kd_back_off: int | None  # Step 3's "reduce it": None, to the largest k_d whose run does not oscillate; n rungs
    rms_target: float | None

    @classmethod
    def from_table(cls, t: Table, campaign: Any) -> Guideline3:
        _check_kind(campaign, ("mfc2",), cls.name)
        rho = t.number("rho", REQUIRED, lo=0.0)
        delay = t.number("delay", None, lo=0.0)
        delay = loop_delay(campaign) if delay is None else delay
        margin = t.number("start_margin", 0.95, lo=0.0, hi=1.0)
        kp0, kd0 = ultralocal_start(rho, delay)
        kp0 *= margin
        per_decade = t.integer("per_decade", 16, 1, 1000)
        kd1, kp1 = t.number("kd_stop", REQUIRED, lo=0.0), t.number("kp_stop", REQUIRED, lo=0.0)
        _ladder("kd_stop", kd0, kd1, per_decade, False)
        _ladder("kp_stop", kp0, kp1, per_decade, False)
        raw = t.raw("kd_back_off")
        back_off = None if raw in (None, "oscillation") else t.integer("kd_back_off", 1, 1, 100)
        return cls(rho, kp0, kd0, kd1, kp1, per_decade, back_off, t.number("rms_target", None, lo=0.0))

    def plan(self) -> Plan:
        kds = Ladder(self.kd_start, self.kd_stop, self.per_decade).values()
        kps = Ladder(self.kp_start, self.kp_stop, self.per_decade).values()  # kps[0]: k̃_p as both stages write it
        base = {GAMMA: self.rho}
        s3 = yield from walk("step 3: raise k_d", [{**base, KP: kps[0], KD: kd} for kd in kds])
        if s3.reason != "tripped":
            kd = s3.seen[-1].params[KD] if s3.reason == "end of range" else None
        elif self.kd_back_off is None:  # Step 3: "reduce it such that no oscillations occur"
            calm = [o.params[KD] for o in s3.seen if o.completed and not o.oscillating]
            kd = max(calm) if calm else None
        else:
            i = kds.index(s3.seen[-1].params[KD]) - self.kd_back_off
            kd = kds[i] if i >= 0 else None
        if kd is None:
            return Result(s3.chosen, f"step 3: {s3.reason}", _stages(s3))
        s4 = yield from walk(  # Step 4: "until either the controlled system starts oscillating or ..."
            f"step 4: raise k_p (k_d = {kd:.5g})",
            [{**base, KP: kp, KD: kd} for kp in kps],
            target=self.rms_target,
            oscillation=True,
        )
        return Result(s4.chosen, s4.reason, {**_stages(s3, s4), "k_d": kd})

    def max_runs(self) -> int:
        return len(Ladder(self.kd_start, self.kd_stop, self.per_decade).values()) + len(
            Ladder(self.kp_start, self.kp_stop, self.per_decade).values()
        )

    def corners(self) -> list[dict[str, Any]]:
        return [
            {GAMMA: self.rho, KP: kp, KD: kd}
            for kp in (self.kp_start, self.kp_stop)
            for kd in (self.kd_start, self.kd_stop)
        ]

    def describe(self) -> str:
        return (
            f"Guideline 3: γ = ρ = {self.rho:.6g}; k_d {self.kd_start:.4g} → {self.kd_stop:.4g} at k_p = "
            f"{self.kp_start:.5g} until a trip, back "
            f"{'to the largest k_d not oscillating' if self.kd_back_off is None else self.kd_back_off}; "
            f"then k_p → {self.kp_stop:.5g} until a trip or an oscillation"
        )


def ultralocal_start(rho: float, delay: float, n: int = 400) -> tuple[float, float]:
    """(k̃_p, k̃_d) of Guideline 3 Step 2: the highest k_p of the ultra-local stability set (thesis
    appendix A.4, corrected closed forms of :mod:`labrunner.stability`) and the k_d where it occurs
    (scanned over the open k_d interval)."""
    from labrunner.stability import bounds

    kd_lo, kd_hi = bounds("mfc2-ultralocal", gamma=rho, delay=delay, rho=rho, k_d=1e-9 / delay)["k_d"]
    best_kp, best_kd = -1.0, 0.0
    for j in range(1, n):
        kd = kd_lo + (kd_hi - kd_lo) * j / n
        kp = bounds("mfc2-ultralocal", gamma=rho, delay=delay, rho=rho, k_d=kd)["k_p"]
        if kp is not None and kp[1] > best_kp:
            best_kp, best_kd = kp[1], kd
    return best_kp, best_kd
