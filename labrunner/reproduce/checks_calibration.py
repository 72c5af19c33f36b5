"""Calibrate on one experiment, validate on another: the motor twin's backlash (``labrunner reproduce``
item calib-motor). Same contract as :mod:`labrunner.reproduce.checks`.

The twin's low-γ edge lies one or two 1/16-decade rungs below the thesis's (feed-forward stage of
Fig. 3.21: aborted below 64.93 on the motor, below 48.7 on the twin). Of the twin's assumed
parameters only the gearbox backlash moves that edge (electrical lag and Coulomb friction do not:
see the calibration campaign's header). The backlash is fitted on Fig. 3.21's edge and the fitted
twin is judged on a different experiment, Table 3.1's unstable differentiators; the calibration's
residual is reported, never counted as agreement.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd

from labrunner.reproduce.checks import unstable_differentiators
from labrunner.reproduce.checks_walks import RUNG
from labrunner.reproduce.verdict import NO_REF, Part, Ref, Results, Verdict, combine, one

GAMMA, BACKLASH = "controller.gamma", "rig_parameters.backlash"
#: Thesis Sec. 3.5.3, Fig. 3.21: the feed-forward stage is aborted below this γ_Ω [rad/(V s²)].
THESIS_EDGE = 64.93


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
    run = one(results, "table3-1")
    at = np.isclose(run.frame[BACKLASH], fitted)
    if not at.any():
        validation = Part(
            "validation: Table 3.1 with the fitted backlash",
            f"the validation grid has no backlash {fitted:g} rad",
            None,
        )
        return combine([calibration, validation], table.round(3))
    verdict = unstable_differentiators({run.file: replace(run, frame=run.frame[at].reset_index(drop=True))})
    validation = Part(
        f"validation on a different experiment: Table 3.1's unstable differentiators with backlash {fitted:g} rad",
        verdict.measured,
        verdict.agrees,
    )
    return combine([calibration, validation], table.round(3))
