"""Calibrate on one experiment, validate on another (``labrunner reproduce`` items calib-motor and
calib-valve). Same contract as :mod:`labrunner.reproduce.checks`: the calibration's residual is reported,
never counted as agreement; the verdict is the validation's, on a different experiment of the source.

calib-motor: the twin's low-γ edge lies one or two 1/16-decade rungs below the thesis's (feed-forward
stage of Fig. 3.21: aborted below 64.93 on the motor, below 48.7 on the twin). Of the twin's assumed
parameters only the gearbox backlash moves that edge (electrical lag and Coulomb friction do not: see the
calibration campaign's header). The backlash is fitted on Fig. 3.21's edge and the fitted twin is judged
on Table 3.1's unstable differentiators.

calib-valve: far above paper 1 Fig. 5's stability region the current switches between i_min and i_max
and the RMS of e_q (≈ 8 l/min on the test bed, 12.9 on the twin as shipped) is the valve's, not the
gains'. Of the valve twin's assumed parameters, the return path's conductance sets that level (it caps
the flow of the open valve); the others move it little or change the cycle's shape (the campaign's
header). The conductance is fitted on that level and the fitted twin is judged on Figs. 9/10 (Sec. 5.3).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from labrunner.analysis.agreement import observed_outcome
from labrunner.reproduce.checks import unstable_differentiators
from labrunner.reproduce.checks_papers import mfc_below_ffc
from labrunner.reproduce.checks_walks import RUNG
from labrunner.reproduce.verdict import NO_REF, Part, Ref, Results, Verdict, combine, one

GAMMA, BACKLASH = "controller.gamma", "rig_parameters.backlash"
#: Thesis Sec. 3.5.3, Fig. 3.21: the feed-forward stage is aborted below this γ_Ω [rad/(V s²)].
THESIS_EDGE = 64.93
#: Paper 1 Sec. 5.1, Fig. 5: the RMS of e_q of the oscillating runs above the stability region [l/min].
PAPER1_SATURATED_RMS = 8.0
RETURN_PATH = "rig_parameters.downstream_conductance"
#: Steady-state accuracy (paper 1 Sec. 5.3): RMS(e_q) over the last second at the end value below this
#: [l/min], 1 % of the flow sensor's 20 l/min range; a settled loop on the twin holds a few hundredths.
SETTLED_TOL = 0.2
#: How closely paper 1's "approximately 8 l/min", read off a colour scale, places the level (item valve-5's
#: 6–10 l/min): the validation is also shown, not judged, for every conductance of the ladder within it.
READING = 0.25


def runs_at(results: Results, files: Sequence[str], key: str, value: float) -> Results | None:
    """The runs of the validation ``files`` (parts of their names) whose ``key`` is ``value``, each file's
    metrics and grid parameters cut alike; None when a file's grid lacks the value."""
    runs = {}
    for file, run in results.items():
        if any(f in Path(file).name for f in files):
            at = np.isclose(run.frame[key], value)
            if not at.any():
                return None
            params = [run.parameters[i] for i in np.flatnonzero(at)] if run.parameters else []
            runs[file] = replace(run, frame=run.frame[at].reset_index(drop=True), parameters=params)
    return runs


def validated(
    calibration: Part,
    table: pd.DataFrame,
    runs: Results | None,
    what: str,
    check: Callable[[Results], Verdict],
    note: str = "",
) -> Verdict:
    """The calibration part beside ``check`` on the validation ``runs`` at the fitted value (:func:`runs_at`);
    not testable when a validation grid lacks that value."""
    if runs is None:
        validation = Part(f"validation: {what}", "the validation grid has no run at the fitted value", None)
    else:
        verdict = check(runs)
        validation = Part(f"validation on a different experiment: {what}", verdict.measured, verdict.agrees)
    return combine([calibration, validation], table, note)


def edges(frame: pd.DataFrame) -> pd.DataFrame:
    """Per backlash: the lowest γ of the ladder that completed with every larger γ completed (the edge
    a walk down the ladder finds), and its distance from the thesis's edge in rungs."""
    rows = []
    for backlash, g in frame.groupby(BACKLASH):
        g = g.sort_values(GAMMA, ascending=False)
        ok = (g["outcome"] == "completed").cumprod().astype(bool)
        edge = float(g.loc[ok, GAMMA].min()) if ok.any() else math.nan
        rows.append({"backlash [rad]": backlash, "edge γ_Ω": edge})
    out = pd.DataFrame(rows)
    out["rungs from the thesis's"] = np.log(out["edge γ_Ω"] / THESIS_EDGE) / math.log(RUNG)
    return out


def calib_backlash(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fit the backlash on Fig. 3.21's feed-forward edge (``ref["edge"]`` in place of the thesis's 64.93:
    a variant's), then judge Table 3.1 on the twin with that backlash (:func:`unstable_differentiators`)."""
    target = float(ref.get("edge", THESIS_EDGE))
    table = edges(one(results, "feedforward").frame)
    residual = np.abs(np.log(table["edge γ_Ω"] / target) / math.log(RUNG))
    best = table.loc[residual.idxmin()] if residual.notna().any() else None
    if best is None:
        return combine([Part("the backlash fits Fig. 3.21's edge", "no ladder completed", None)], table)
    fitted, rungs = float(best["backlash [rad]"]), float(residual.min())
    calibration = Part(
        f"calibration: the backlash whose feed-forward edge is nearest γ_Ω = {target:g} (Fig. 3.21)",
        f"backlash {fitted:g} rad (shipped: 0.02 rad), edge {best['edge γ_Ω']:.4g}, residual {rungs:.2f} rungs; "
        "edges " + ", ".join(f"{b:g} rad → {e:.4g}" for b, e in zip(table["backlash [rad]"], table["edge γ_Ω"])),
        None,
    )
    return validated(
        calibration,
        table.round(3),
        runs_at(results, ("table3-1",), BACKLASH, fitted),
        f"Table 3.1's unstable differentiators with backlash {fitted:g} rad",
        unstable_differentiators,
    )


def saturated_levels(frame: pd.DataFrame, shipped: dict[str, float], i_max: float) -> pd.DataFrame:
    """Per row of the calibration's zip (at most one assumed parameter off the ``shipped`` twin): that
    parameter and its value, the mean RMS(e_q) over the row's gains, their spread, and whether every run
    oscillates at i_max (the current switching between its limits: the level is then the valve's)."""
    cols = [c for c in frame.columns if c.startswith("rig_parameters.")]
    saturated = (observed_outcome(frame) == "oscillating") & (frame["max_abs_input"] >= 0.99 * i_max)
    rows = []
    for values, g in frame.assign(saturated=saturated).groupby(cols, sort=False):
        values = values if isinstance(values, tuple) else (values,)
        off = [
            (c.split(".", 1)[1], float(v))
            for c, v in zip(cols, values)
            if not np.isclose(v, shipped[c.split(".", 1)[1]])
        ]
        name, value = off[0] if len(off) == 1 else ("shipped twin", math.nan) if not off else ("several", math.nan)
        rows.append(
            {
                "parameter": name,
                "value": value,
                "saturated RMS(e_q) [l/min]": float(g["rms_error"].mean()),
                "spread over k_p [l/min]": float(g["rms_error"].max() - g["rms_error"].min()),
                "saturated runs": f"{int(g['saturated'].sum())} of {len(g)}",
                "all saturated": bool(g["saturated"].all()),
            }
        )
    return pd.DataFrame(rows)


def calib_valve(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fit the valve's return-path conductance on Fig. 5's saturated RMS (``ref["level"]`` in place of the
    paper's 8 l/min: a variant's) among the calibration rows that vary it alone, every run saturated; then
    judge Figs. 9/10 on the twin with that conductance: the MFC's RMS below the FFC's at every end value
    (:func:`mfc_vs_ffc`) and the MFC settled at every end value (Sec. 5.3: steady-state accuracy)."""
    from labrunner.campaign import runner, spec

    target = float(ref.get("level", PAPER1_SATURATED_RMS))
    run = one(results, "saturated")
    rig = spec.load(run.directory / runner.CAMPAIGN_COPY, root=spec.project_root(Path(run.file))).rig_config
    table = saturated_levels(run.frame, dict(rig.parameters), float(rig.parameters["i_max"]))
    name = RETURN_PATH.split(".", 1)[1]
    shipped = float(rig.parameters[name])
    ladder = table[table["parameter"].isin((name, "shipped twin")) & table["all saturated"]]
    ladder = ladder.assign(value=ladder["value"].fillna(shipped)).sort_values("value")
    level = "saturated RMS(e_q) [l/min]"
    if ladder.empty:
        return combine([Part("the return path fits Fig. 5's saturated RMS", "no row saturated", None)], table)
    best = ladder.loc[(ladder[level] - target).abs().idxmin()]
    fitted = float(best["value"])
    others = table[~table["parameter"].isin((name, "shipped twin"))]
    calibration = Part(
        f"calibration: the return-path conductance whose saturated RMS(e_q) is nearest {target:g} l/min (Fig. 5)",
        f"{name} {fitted:g} (l/min)/√bar (shipped: {shipped:g}), saturated RMS {best[level]:.2f} l/min, residual "
        f"{abs(best[level] - target):.2f} l/min; ladder "
        + ", ".join(f"{v:g} → {r:.2f}" for v, r in zip(ladder["value"], ladder[level]))
        + (
            "; the others' levels "
            + ", ".join(
                f"{p} {g[level].min():.2f}–{g[level].max():.2f}" for p, g in others.groupby("parameter", sort=False)
            )
            if len(others)
            else ""
        ),
        None,
    )
    files = ("fig09-10-mfc", "fig09-10-ffc")
    band = ladder[(ladder[level] - target).abs() <= READING * target]
    checked = [(v, runs_at(results, files, RETURN_PATH, v)) for v in band["value"]]
    verdicts = {v: settled_and_lower(r).agrees for v, r in checked if r is not None}
    note = (
        f"Not judged: the ladder within ±{READING:.0%} of {target:g} l/min (a colour scale's reading, item valve-5): "
        + ", ".join(f"{v:g} → {r:.2f}" for v, r in zip(band["value"], band[level]))
        + "; the validation there "
        + ", ".join(f"{v:g}: {'agrees' if a else 'disagrees'}" for v, a in verdicts.items())
    )
    return validated(
        calibration,
        table.drop(columns="all saturated").round(3),
        runs_at(results, files, RETURN_PATH, fitted),
        f"Figs. 9/10 with the return path {fitted:g} (l/min)/√bar",
        settled_and_lower,
        note if verdicts else "",
    )


def settled_and_lower(results: Results) -> Verdict:
    """Paper 1 Sec. 5.3: the MFC's RMS(e_q) is below the FFC's at every end value (:func:`mfc_below_ffc`),
    and the MFC is steady-state accurate (Fig. 9 settles at 14 l/min): RMS(e_q) over the last second at
    each end value below :data:`SETTLED_TOL`."""
    run = one(results, "-mfc")
    ends = np.array([float(p["reference.levels"][1]) for p in run.parameters])
    settled = run.frame["rms_error@settled"].to_numpy()
    off = ends[~(settled < SETTLED_TOL)]
    lower, table = mfc_below_ffc(results)
    parts = [
        lower,
        Part(
            f"the MFC settles at every end value (RMS(e_q) of the last second at it below {SETTLED_TOL:g} l/min)",
            f"{settled.min():.3f}–{settled.max():.3f} l/min; "
            + (f"not at {', '.join(f'{e:g}' for e in off)} l/min" if len(off) else f"at all {len(ends)}"),
            bool(len(ends) and not len(off)),
        ),
    ]
    return combine(parts, table.assign(**{"MFC settled": settled}))
