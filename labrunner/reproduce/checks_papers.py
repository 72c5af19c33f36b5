"""Checks of ``labrunner reproduce`` for paper 1 (the proportional valve).

Same contract as :mod:`labrunner.reproduce.checks`: each claim tested as the paper states it, part by
part. Paper 2 (the plate): :mod:`labrunner.reproduce.checks_plate`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from labrunner.analysis.agreement import observed_outcome
from labrunner.reproduce.verdict import NO_REF, Part, Ref, Results, Verdict, combine, grid_index, one, unstable


def valve_region(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Paper 1 Fig. 5 / Sec. 5.1: above the stability region the flow oscillates with the maximal current and
    RMS(e_q) ≈ 8 l/min (``ref["rms"]``: the band, a variant's); below it the current is too small to
    provide a flow."""
    lo, hi = ref.get("rms", (6.0, 10.0))
    frame = one(results).frame.copy()
    frame["class"] = observed_outcome(frame)
    osc = frame[frame["class"] == "oscillating"]
    at_max = osc["max_abs_input"] >= 0.99 * 1.01
    rms = osc["rms_error"]
    parts = [
        Part(
            "above the region the flow oscillates with the maximal current",
            f"{len(osc)} runs oscillating, {int(at_max.sum())} of them at i_max",
            bool(len(osc) and at_max.all()),
        ),
        Part(
            f"there RMS(e_q) in {lo:g}–{hi:g} l/min (≈ 8 ± 25 %: read off a colour scale)",
            f"{rms.min():.2f}–{rms.max():.2f} l/min" if len(rms) else "no oscillating run",
            bool(len(rms) and rms.between(lo, hi).all()),
        ),
        Part(
            "below it the current is too small to move the main spool",
            f"{int((frame['class'] == 'no-motion').sum())} runs never opened the main stage",
            bool((frame["class"] == "no-motion").any()),
        ),
    ]
    return combine(parts, frame[["controller.gamma", "controller.k_p", "class", "rms_error", "max_abs_input"]].round(3))


def valve_parametrisations(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Paper 1 Fig. 7: all six parametrisations give a stability region "of the same shape in approximately
    the same parameter set": every (γ, k_p) cell classified unlike No. 1 lies next to No. 1's boundary
    (one grid step), i.e. the region moves by at most one grid step. ``ref["shift"]``: No. 1's map
    moved by that many k_p grid steps (a variant's; cells it leaves are stable)."""
    shift = int(ref.get("shift", 0))
    frame = one(results).frame.copy()
    frame["unstable"] = unstable(frame)
    keys = ["controller.gamma", "controller.k_p"]
    groups = list(frame.groupby(["differentiator.alpha", "differentiator.omega_c"], sort=False))
    ref_map = groups[0][1].reset_index(drop=True)
    index = {(p[0], p[1] + shift): u for p, u in zip(grid_index(ref_map, keys), ref_map["unstable"])}
    index.update({p: False for p in map(tuple, grid_index(ref_map, keys)) if p not in index})

    def edge(pos: tuple[int, int]) -> bool:
        return any(
            index.get((pos[0] + dx, pos[1] + dy), index[pos]) != index[pos]
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
        )

    rows = []
    for (alpha, omega), g in groups:
        g = g.reset_index(drop=True)
        pos = [tuple(p) for p in grid_index(g, keys)]
        differ = [p for p, u in zip(pos, g["unstable"]) if index.get(p) is not None and index[p] != u]
        rows.append(
            {
                "α = β": int(alpha),
                "ω_c [rad/s]": omega,
                "unstable": int(g["unstable"].sum()),
                "oscillating (detector)": int((observed_outcome(g) == "oscillating").sum()),
                "cells unlike No. 1": len(differ),
                "of them off No. 1's boundary": sum(not edge(p) for p in differ),
            }
        )
    table = pd.DataFrame(rows)
    off = int(table["of them off No. 1's boundary"].sum())
    part = Part(
        "all six parametrisations give a stability region of the same shape in about the same place",
        f"{int(table['cells unlike No. 1'].sum())} cells classified unlike No. 1, {off} more than one grid step "
        "from No. 1's boundary",
        off == 0,
    )
    return combine([part], table)


#: Paper 1 Sec. 5.1: the parameters chosen as a good trade-off (γ [m³/(A s²)], k_p [1/s]).
PAPER1_CHOICE = (0.4, 30.0)


def valve_lines(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Paper 1 Fig. 8 / Sec. 5.2: the lines behave alike; from (C) to (B) the errors shrink; on (A) the flow
    oscillates "but the current is not reaching its maximum value i_max yet". The lines are ordered by
    γ/k_p: (A) the smallest ratio (the most aggressive), (C) the largest. The campaign draws line (A)
    through the paper's chosen point, a "good trade-off": that point must not oscillate, else the
    line's oscillation is the pack's placement, not the paper's line."""
    from labrunner.reproduce.checks import ratio_lines

    alike, lines = ratio_lines(results, ref)
    frame = one(results).frame
    at = frame[
        np.isclose(frame["controller.gamma"], PAPER1_CHOICE[0]) & np.isclose(frame["controller.k_p"], PAPER1_CHOICE[1])
    ]
    status = observed_outcome(at)
    choice = Part(
        "the paper's chosen point γ = 0.4, k_p = 30 (on line (A)) is a good trade-off: it does not oscillate",
        ", ".join(status) if len(at) else "not on the grid",
        bool((status == "completed").all()) if len(at) else None,
    )
    if len(lines) < 3:
        return combine([alike, choice], lines)
    a, b, c = (lines.iloc[i] for i in (0, 1, 2))
    parts = [
        alike,
        Part(
            "from line (C) to (B) the errors shrink",
            f"mean RMS(e_q) (C) {c['mean_rms']:.3g}, (B) {b['mean_rms']:.3g} l/min",
            bool(b["mean_rms"] < c["mean_rms"]),
        ),
        Part(
            "on line (A) the flow oscillates with the current below i_max",
            f"(A) {a['classes']}, largest current {a['max_input']:.3g} A",
            bool(a["classes"] == "unstable" and a["max_input"] < 0.99 * 1.01),
        ),
        choice,
    ]
    return combine(parts, lines)


def mfc_vs_ffc(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Paper 1 Fig. 10: the MFC's RMS(e_q) is below the FFC's at every end value."""
    part, table = mfc_below_ffc(results)
    return combine([part], table)


def mfc_below_ffc(results: Results) -> tuple[Part, pd.DataFrame]:
    """Fig. 10's part and its table (RMS(e_q) of the MFC and the FFC per end value), for reuse (calib-valve)."""
    rows = {}
    for name in ("mfc", "ffc"):
        run = one(results, f"-{name}")
        ends = [float(p["reference.levels"][1]) for p in run.parameters]
        rows[name.upper()] = pd.Series(run.frame["rms_error@tracking"].to_numpy(), index=ends)
    table = pd.DataFrame(rows).rename_axis("end flow [l/min]")
    lower = table["MFC"] < table["FFC"]
    part = Part(
        "the MFC's RMS(e_q) is below the FFC's for every end value of the commanded flow",
        f"MFC {table['MFC'].min():.2f}–{table['MFC'].max():.2f} l/min, FFC {table['FFC'].min():.2f}–"
        f"{table['FFC'].max():.2f} l/min; lower at {int(lower.sum())} of {len(table)} end values",
        bool(lower.all()),
    )
    return part, table.reset_index()
