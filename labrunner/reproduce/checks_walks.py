"""Checks of ``labrunner reproduce`` for thesis Sec. 3.5.3: Polack et al. vs Guideline 2 on the motor twin.

The two procedures run as guided campaigns (``campaigns/guided/polack.toml``, ``guideline2-case1.toml``:
the procedures of :mod:`labrunner.campaign.guided_walks`, each choosing its next run from the outcomes so
far). Steps are counted as the thesis counts them — a step is a change of the setting from the start:

- Polack's feed-forward stage: 66 = 10⁶ → 74.98 in 1/16 decades (4.125 × 16);
- its feedback stage: 41 = k_p from 0 (the feed-forward stage) to 0.1, then 0.1 → 31.62 (1 + 2.5 × 16);
- Guideline 2: 54 = γ 10⁶ → 421.69 along k_p = 10⁵/γ (3.375 × 16), the first run as good as Polack's.

Runs past the choice (the procedure only knows where to stop once the loop has tripped) are not steps.
A gain "agrees" within one rung of the 16-per-decade ladder (a factor 10^(1/16) ≈ 1.155): the procedure
cannot place it closer.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from labrunner.reproduce.verdict import NO_REF, Part, Ref, Results, Verdict, combine

GAMMA, KP = "controller.gamma", "controller.k_p"
RUNG = 10 ** (1 / 16)


def _state(results: Results, name: str) -> Any:
    from labrunner.campaign import guided_run

    run = next(r for f, r in results.items() if name in f.rsplit("/", 1)[-1])
    return guided_run.directory_state(run.directory)[1], run


def _stages(state: Any) -> dict[str, list]:
    out: dict[str, list] = {}
    for step in state.walk:
        out.setdefault(step.stage, []).append(step.observation)
    return out


def walks(results: Results, target: float = 1.0) -> dict[str, Any]:
    """:func:`facts` of the two guided campaigns of ``results``."""
    polack, prun = _state(results, "polack")
    g2, grun = _state(results, "guideline2")
    return {**facts(polack, g2, target), "dirs": {"polack": prun, "guideline2": grun}}


def facts(polack: Any, g2: Any, target: float = 1.0) -> dict[str, Any]:
    """The facts of both walks (two replayed procedures, :class:`~labrunner.campaign.guided.Advance`):
    chosen points, steps as the thesis counts them (Guideline 2's to ``target`` × Polack's RMS), runs made."""
    ff, fb = (list(v) for v in _stages(polack).values()) if len(_stages(polack)) == 2 else ([], [])
    ff_choice = next((o for o in ff if fb and o.params[GAMMA] == fb[0].params[GAMMA]), None)
    chosen = polack.result.chosen if polack.result else None
    n_ff = ff.index(ff_choice) if ff_choice else None
    n_fb = fb.index(chosen) + 1 if chosen in fb else None
    g2_obs = [s.observation for s in g2.walk]
    reach = next(
        (i for i, o in enumerate(g2_obs) if chosen and o.completed and o.rms_error <= target * chosen.rms_error), None
    )
    best_ff = min((o for o in ff if o.completed), key=lambda o: o.rms_error, default=None)
    trip = next((o for o in ff if o.tripped), None)
    return {
        "ff": ff,
        "fb": fb,
        "ff_choice": ff_choice,
        "best_ff": best_ff,
        "ff_trip": trip,
        "chosen": chosen,
        "g2": g2_obs[reach] if reach is not None else None,
        "steps": {"polack_ff": n_ff, "polack_fb": n_fb, "guideline2": reach},
        "runs": {"polack": polack.runs, "guideline2": g2.runs},
    }


def _near(value: float | None, thesis: float) -> bool:
    return value is not None and math.isfinite(value) and abs(math.log(value / thesis)) <= math.log(RUNG) * 1.01


def _fmt(value: float | None) -> str:
    return "—" if value is None else f"{value:.5g}"


def polack_stages(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.21: the feed-forward stage trips below γ_Ω = 64.93 and picks 74.98; the feedback stage picks
    k_p = 31.62 (each within one rung), a satisfactory loop: the detector does not flag it oscillating.
    ``ref["scale"]`` multiplies the thesis's gains (a variant's)."""
    w = walks(results)
    x = float(ref.get("scale", 1.0))
    last_ok = next((o for o in reversed(w["ff"]) if o.completed), None) if w["ff"] else None
    gamma = w["ff_choice"].params[GAMMA] if w["ff_choice"] else None
    kp = w["chosen"].params[KP] if w["chosen"] else None
    parts = [
        Part(
            "feed-forward (k_p = 0): aborted below γ_Ω = 64.93",
            f"last stable γ_Ω {_fmt(last_ok.params[GAMMA] if last_ok else None)}, first trip at "
            f"{_fmt(w['ff_trip'].params[GAMMA] if w['ff_trip'] else None)}",
            _near(last_ok.params[GAMMA] if last_ok else None, 64.93 * x),
        ),
        Part(f"the feed-forward stage picks γ_Ω = {74.98 * x:.4g}", f"γ_Ω = {_fmt(gamma)}", _near(gamma, 74.98 * x)),
        Part(f"the feedback stage picks k_p = {31.62 * x:.4g}", f"k_p = {_fmt(kp)}", _near(kp, 31.62 * x)),
        _satisfactory(w),
    ]
    return combine(parts, _walk_table(w))


def _satisfactory(w: dict[str, Any]) -> Part:
    """Polack's chosen loop is the thesis's "satisfactory" one: completed and not flagged oscillating."""
    chosen = w["chosen"]
    flagged = [o for o in w["fb"] if o.completed and o.oscillating]
    return Part(
        "the procedure ends at a satisfactory (non-oscillating) loop",
        "no choice"
        if chosen is None
        else f"the chosen k_p = {chosen.params[KP]:.4g} is {'flagged' if chosen.oscillating else 'not flagged'} "
        f"oscillating by the detector; {len(flagged)} of {len(w['fb'])} feedback runs flagged",
        chosen is not None and chosen.completed and not chosen.oscillating,
    )


def _premise(w: dict[str, Any]) -> Part:
    """The premise of the Sec. 3.5.3 comparisons: Polack's result is a satisfactory loop. Where the
    detector flags it, a comparison with it is not the thesis's: the part is undecided."""
    part = _satisfactory(w)
    if part.agrees:
        return part
    return Part(part.claim, part.measured, None, "the comparison is made against an oscillating loop")


def backoff(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.22: the smallest-RMS feed-forward γ_Ω (64.93) oscillates as Ω_r returns to zero, so the next
    larger one (74.98) is chosen (``ref["direction"] = -1``: the next smaller, a variant's)."""
    w = walks(results)
    direction = ref.get("direction", 1)
    best, pick = w["best_ff"], w["ff_choice"]
    if best is None or pick is None:
        return combine(
            [Part("the smallest-RMS γ_Ω oscillates; the next larger is chosen", "no feed-forward choice", False)]
        )
    oscillates = bool(best.oscillating)
    part = Part(
        "the smallest-RMS γ_Ω oscillates when Ω_r returns to zero, so the next larger γ_Ω is chosen",
        f"smallest RMS at γ_Ω = {best.params[GAMMA]:.5g} ({'oscillating' if oscillates else 'not flagged oscillating'}"
        f" by the detector), chosen {pick.params[GAMMA]:.5g}",
        oscillates and direction * (pick.params[GAMMA] - best.params[GAMMA]) > 0,
    )
    return combine([part])


def guideline2(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.23: Guideline 2 reaches Polack's RMS (0.29 rad/s) at γ_Ω = 421.69, k_p = 237.13
    (``ref["scale"]`` multiplies the thesis's numbers: a variant's)."""
    w = walks(results)
    g = w["g2"]
    x = float(ref.get("scale", 1.0))
    target = w["chosen"].rms_error if w["chosen"] else math.nan
    parts = [
        Part(
            f"Polack's result has RMS(e_Ω) = {0.29 * x:.3g} rad/s (±10 %: two printed digits and the twin's noise)",
            f"{target:.3g} rad/s",
            bool(abs(target / (0.29 * x) - 1) <= 0.1),
        ),
        Part(
            f"Guideline 2 reaches that RMS at γ_Ω = {421.69 * x:.5g}, k_p = {237.13 * x:.5g}",
            f"γ_Ω = {_fmt(g.params[GAMMA] if g else None)}, k_p = {_fmt(g.params[KP] if g else None)}",
            _near(g.params[GAMMA] if g else None, 421.69 * x),
        ),
    ]
    return combine(parts, _walk_table(w))


def step_counts(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Sec. 3.5.3: Guideline 2 needs 54 steps, Polack et al. 66 + 41 = 107: fewer steps with Guideline 2
    to Polack's result (``ref["target"]`` × its RMS: a variant's); undecided if that result oscillates."""
    w = walks(results, float(ref.get("target", 1.0)))
    s = w["steps"]
    polack = s["polack_ff"] + s["polack_fb"] if s["polack_ff"] is not None and s["polack_fb"] is not None else None
    g2 = s["guideline2"]
    table = pd.DataFrame(
        {
            "thesis": [66, 41, 107, 54],
            "twin (steps as the thesis counts)": [s["polack_ff"], s["polack_fb"], polack, g2],
        },
        index=["Polack feed-forward", "Polack feedback", "Polack total", "Guideline 2"],
    ).reset_index(names="walk")
    part = Part(
        "Guideline 2 reaches Polack's RMS in fewer steps (54 vs 107)",
        f"{_fmt(g2)} vs {_fmt(polack)} steps (runs made, trips included: {w['runs']['guideline2']} vs {w['runs']['polack']})",
        None if polack is None else g2 is not None and g2 < polack,
    )
    return combine([part, _premise(w)], table)


def input_noise(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.24: Guideline 2's result has a less noisy input u than Polack's (its γ_Ω is higher);
    undecided if Polack's result oscillates. ``ref["polack"] = "first"`` takes Polack's first
    feed-forward run (γ_Ω = 10⁶) in place of its result (a variant's)."""
    from labrunner.logs import read_run

    w = walks(results)
    polack = next((o for o in w["ff"] if o.completed), None) if ref.get("polack") == "first" else w["chosen"]
    noise = {}
    for key, obs in (("polack", polack), ("guideline2", w["g2"])):
        if obs is None:
            return combine([Part("Guideline 2's input is less noisy", f"{key} chose nothing", False)])
        run = w["dirs"][key]
        rel = run.frame.loc[run.frame["id"] == obs.id, "log_path"].iloc[0]
        log = read_run(run.directory / "report" / rel)
        u = log.signal("u")
        noise[key] = float(np.sqrt(np.mean(np.diff(u[int(3.5 * log.fs) :]) ** 2)))  # at rest: after the reference
    part = Part(
        "Guideline 2's input u is less noisy than Polack's",
        f"RMS of Δu at rest (t > 3.5 s): Guideline 2 {noise['guideline2']:.3g} V, Polack {noise['polack']:.3g} V",
        noise["guideline2"] < noise["polack"],
    )
    return combine([part, _premise(w)])


def _walk_table(w: dict[str, Any]) -> pd.DataFrame:
    rows = [
        {
            "stage": stage,
            "γ_Ω": o.params.get(GAMMA),
            "k_p": o.params.get(KP),
            "status": o.status,
            "rms_error": o.rms_error,
        }
        for stage, obs in (("feed-forward", w["ff"][-6:]), ("feedback", w["fb"][-6:]))
        for o in obs
    ]
    return pd.DataFrame(rows)
