"""What the analysis shows of a guided campaign, and the Guideline 2 vs Polack comparison.

:func:`sections` adds to ``labrunner analyse``'s report the walk of the procedure (a table, as
``walk.csv``, and a plot of RMS(e) and the gains over the steps, stage by stage, like thesis
Figs. 3.21 and 3.23) and its step counts. A refinement's boundary shows on the ordinary map (its
points lie on the fine lattice); its section states the runs against the full grid.

:func:`compare_guideline2_polack` runs the two shipped campaigns of thesis Sec. 3.5.3 on the motor
twin and returns their step counts beside the thesis's (54 vs 107).
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from labrunner import safefs
from labrunner.campaign.guided import Advance

#: Thesis Sec. 3.5.3: Guideline 2 took 54 steps, Polack et al. 66 (feed-forward) + 41 (feedback) = 107.
THESIS_STEPS = {"guideline2": 54, "polack": 107, "polack_feed_forward": 66, "polack_feedback": 41}
_MARKERS = {"completed": ("x", "black"), "aborted": ("^", "red"), "no-motion": ("o", "white"), "failed": ("s", "grey")}


def walk_table(state: Advance) -> pd.DataFrame:
    """One row per step of the walk: step (1-based), stage, point id, its parameters, outcome, metrics,
    whether it was run there (``new``) or an earlier run was reused."""
    chosen = state.result.chosen.id if state.result is not None and state.result.chosen is not None else None
    rows = []
    for n, step in enumerate(state.walk, start=1):
        o = step.observation
        rows.append(
            {
                "step": n,
                "stage": step.stage,
                "id": o.id,
                **{k: v for k, v in o.params.items()},
                "status": o.status,
                "rms_error": o.rms_error,
                "input_energy": o.input_energy,
                "new": step.new,
                "chosen": o.id == chosen,
            }
        )
    return pd.DataFrame(
        rows, columns=None if rows else ["step", "stage", "id", "status", "rms_error", "input_energy", "new", "chosen"]
    )


def walk_figure(table: pd.DataFrame, title: str):
    """RMS(e) over the steps (top) and the varied gains (bottom, log scale), stage boundaries dashed."""
    from matplotlib.figure import Figure

    gains = [
        c for c in table.columns if "." in c and pd.api.types.is_numeric_dtype(table[c]) and table[c].nunique() > 1
    ]
    fig = Figure(figsize=(9, 6), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    # an aborted run's RMS (up to the abort) would look better than the runs around it: at the top,
    # marker and line alike
    drawn = table["rms_error"].where(table["status"] != "aborted")
    drawn = drawn.fillna(table["rms_error"].max() if table["rms_error"].notna().any() else 1.0)
    for status, (marker, colour) in _MARKERS.items():
        part = table["status"] == status
        if not part.any():
            continue
        edge = None if marker == "x" else "black"  # an unfilled marker takes its colour only
        top.scatter(table["step"][part], drawn[part], marker=marker, c=colour, edgecolors=edge, label=status, zorder=3)
    top.plot(table["step"], drawn, color="0.7", zorder=1)
    picked = table[table["chosen"]]
    if not picked.empty:
        top.scatter(
            picked["step"],
            picked["rms_error"],
            s=180,
            facecolors="none",
            edgecolors="tab:blue",
            label="chosen",
            zorder=4,
        )
    top.set_yscale("log")
    top.set_ylabel("RMS(e) (aborted: drawn at the top)")
    top.legend(loc="best", fontsize="small")
    for key in gains:
        values = table[key].where(table[key] > 0)
        bottom.plot(table["step"], values, marker=".", label=key.split(".")[-1])
    if gains:
        bottom.set_yscale("log")
        bottom.legend(loc="best", fontsize="small")
    bottom.set_xlabel("step")
    bottom.set_ylabel("gain")
    starts = table.groupby("stage", sort=False)["step"].min().iloc[1:]
    for ax in (top, bottom):
        for s in starts:
            ax.axvline(s - 0.5, color="0.4", ls="--", lw=1)
    fig.suptitle(title)
    return fig


def sections(campaign: Any, rows: list[dict[str, Any]], out: Path) -> tuple[list[Any], dict[str, Any]]:
    """Report sections (``labrunner.analysis.report.Section``) and the summary of a guided campaign
    from its ledger ``rows``; writes ``walk.csv`` (and ``walk.png``) into ``out``."""
    from labrunner.analysis.report import Image, Section
    from labrunner.campaign import guided_run

    state, summary = guided_run.replay(campaign, rows), guided_run.summary(campaign, rows)
    table = walk_table(state)
    safefs.write_atomic(out / "walk.csv", table.to_csv(index=False).encode("utf-8"), durable=False)
    facts: dict[str, object] = {
        "procedure": campaign.guided.describe(),
        "runs": state.runs,
        "at most": campaign.guided.max_runs(),
        "state": summary.get("reason", f"running: waits on {len(state.next)} point(s)"),
    }
    for stage, counts in state.stage_counts().items():
        facts[f"stage: {stage}"] = f"{counts['runs']} runs ({counts['steps']} steps)"
    chosen = summary.get("chosen")
    if chosen:
        values = ", ".join(f"{k.split('.')[-1]} = {v:.5g}" for k, v in chosen["params"].items() if isinstance(v, float))
        facts["chosen"] = f"step {chosen['step']}: {values}, RMS(e) = {chosen['rms_error']:.4g}"
    detail = summary.get("detail", {})
    if "boundary_cells" in detail:
        n = detail["resolution"][0]
        facts["boundary"] = (
            f"{len(detail['boundary_cells'])} mixed cells at {n} × {n}; {detail['runs']} runs instead of "
            f"{detail['full_grid_runs']} ({detail['full_grid_runs'] / max(detail['runs'], 1):.1f}× fewer)"
        )
    paragraphs = [
        "A guided campaign's procedure chose each point from the outcomes before it (thesis Sec. 3.5); the walk "
        "lists the points in the order the procedure asked for them. A point asked for again is not run again "
        "(new = false). Step counts compare with the thesis's: Guideline 2 took 54 steps, Polack et al. 66 + 41 "
        "= 107 (Sec. 3.5.3)."
    ]
    if "boundary_cells" in detail:
        paragraphs.append(
            "The refined points lie on the fine lattice and show on the ordinary maps; lattice cells "
            "the refinement did not need are not run and stay grey there."
        )
    images = []
    if len(table) and "boundary_cells" not in detail:
        fig = walk_figure(table, f"{campaign.name}: the walk")
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110)
        safefs.write_atomic(out / "walk.png", buf.getvalue(), durable=False)  # never through a planted link
        images.append(Image("The walk", buf.getvalue(), "RMS(e) and the gains at each step; dashed: a new stage."))
    shown = table.drop(columns=["id"]).rename(columns=lambda c: c.split(".")[-1] if "." in c else c)
    tables = [("Walk", shown)] if len(table) <= 400 else [("Walk (first 400 steps; all in walk.csv)", shown.head(400))]
    return [Section("Guided procedure", paragraphs=paragraphs, facts=facts, tables=tables, images=images)], summary


def compare_guideline2_polack(
    out: str | Path, *, workers: int | None = None, stream: TextIO | None = None, campaigns: str | Path | None = None
) -> dict[str, Any]:
    """Run Guideline 2 case 1 and Polack et al.'s procedure on the motor twin; return their step counts.

    Signature for ``labrunner reproduce``::

        compare_guideline2_polack(out: str | Path, *, workers: int | None = None,
                                  stream: TextIO | None = None, campaigns: str | Path | None = None) -> dict

    Runs ``campaigns/guided/guideline2-case1.toml`` and ``polack.toml`` (or those in ``campaigns``)
    into ``out/guideline2`` and ``out/polack`` (resumed if they exist; ≈ 170 runs, ≈ 30 s on 2 cores;
    progress lines go to ``stream``). Returns
    ``{"guideline2": {"runs", "reason", "chosen", "runs_to_polack_rms"}, "polack": {"runs",
    "feed_forward", "feedback", "reason", "chosen"}, "ratio", "thesis": THESIS_STEPS}``: ``chosen`` is
    ``{"id", "params", "rms_error", "step"}``; ``runs_to_polack_rms`` the runs Guideline 2 made up to and
    including its first completed run whose RMS(e) is at most that of Polack's choice (the thesis stopped
    Guideline 2 there; a point the walk looks at again is not a run); ``ratio`` = Polack's runs / those
    runs (thesis, in steps: 107 / 54 ≈ 2; steps as the thesis counts them: ``labrunner reproduce`` item
    3.5.3), ``ratio_runs`` = Polack's runs / Guideline 2's runs up to its trip."""
    from labrunner.campaign import guided_run, runner
    from labrunner.campaign.ledger import LEDGER_NAME

    folder = Path(campaigns) if campaigns else Path(__file__).resolve().parents[2] / "campaigns" / "guided"
    out = Path(out)
    opts = runner.Options(workers=workers, stream=stream or io.StringIO())
    states = []
    for key, name in (("guideline2", "guideline2-case1"), ("polack", "polack")):
        directory = out / key
        if (directory / LEDGER_NAME).exists():
            runner.resume(directory, opts)
        else:
            runner.start(folder / f"{name}.toml", directory, opts)
        states.append(guided_run.directory_state(directory)[1])
    return step_counts(*states)


def _choice(state: Advance) -> dict[str, Any] | None:
    chosen = state.result.chosen if state.result is not None else None
    if chosen is None:
        return None
    step = next(n for n, s in enumerate(state.walk, 1) if s.observation.id == chosen.id)
    return {"id": chosen.id, "params": dict(chosen.params), "rms_error": chosen.rms_error, "step": step}


def _reason(state: Advance) -> str | None:
    return state.result.reason if state.result is not None else None


def step_counts(guideline2: Advance, polack: Advance) -> dict[str, Any]:
    """The comparison of thesis Sec. 3.5.3 from two finished walks (see :func:`compare_guideline2_polack`)."""
    g_choice, p_choice = _choice(guideline2), _choice(polack)
    target = p_choice["rms_error"] if p_choice else None
    at = next(
        (
            n
            for n, s in enumerate(guideline2.walk, 1)
            if target is not None and s.observation.completed and s.observation.rms_error <= target
        ),
        None,
    )
    match = sum(s.new for s in guideline2.walk[:at]) if at else None
    stages = list(polack.stage_counts().values())
    return {
        "guideline2": {
            "runs": guideline2.runs,
            "reason": _reason(guideline2),
            "chosen": g_choice,
            "runs_to_polack_rms": match,
        },
        "polack": {
            "runs": polack.runs,
            "feed_forward": stages[0]["runs"] if stages else 0,
            "feedback": stages[1]["runs"] if len(stages) > 1 else 0,
            "reason": _reason(polack),
            "chosen": p_choice,
        },
        "ratio": polack.runs / match if match else math.nan,
        "ratio_runs": polack.runs / guideline2.runs if guideline2.runs else math.nan,
        "thesis": dict(THESIS_STEPS),
    }
