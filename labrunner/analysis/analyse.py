"""``labrunner analyse``: a campaign directory → metrics table, maps, run plots and index.html.

Steps: read the ledger (parameters, outcomes, every run's metrics) and the campaign file it keeps;
build the metrics table from it (:mod:`.table`; logs are read only where the ledger has no
metrics or with ``recompute``); pick the map axes from the grid (γ–k_p and k_p–k_d as in the
thesis, else grid order; further axes become facets); draw RMS and energy maps (or sweep plots)
with the stability overlays that fit (:mod:`.overlays`); plot the best, the worst completed, the
first aborted run and any runs asked for (the only logs read then); compare outcomes with the
theory (:mod:`.agreement`); write the report. Returns the summary that ``--json`` prints. With
more than one worker the run plots and the second half of the maps are drawn in forked children
(:mod:`.background`) while this process draws the rest.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import pandas as pd

from labrunner.analysis import agreement as agreement_mod, campaign_report, figures, table as table_mod
from labrunner.analysis.background import Background
from labrunner.analysis.context import Context, Theories
from labrunner.analysis.maps import gain_units
from labrunner.campaign import spec
from labrunner.campaign.progress import FINISHED, OUTCOMES
from labrunner.campaign.spec import Campaign
from labrunner.control.mfc import GAMMA_UNITS
from labrunner.errors import InvalidParameter, LabrunnerError

__all__ = ["Context", "Theories", "analyse", "load_campaign", "varying_axes"]

#: Run plots drawn in a forked child while the maps are drawn (more: in this process, with progress).
BACKGROUND_PLOTS = 8


def load_campaign(meta: Mapping[str, str], directory: Path) -> tuple[Campaign | None, str]:
    """The :class:`~labrunner.campaign.spec.Campaign` kept in the ledger, or (None, why not)."""
    text = meta.get("campaign_file")
    if not text:
        return None, "the ledger keeps no copy of the campaign file"
    source = meta.get("campaign_path")
    try:
        return spec.from_text(text, source_path=Path(source) if source else None), ""
    except LabrunnerError as exc:
        return None, f"the campaign file could not be loaded again: {exc}"


def varying_axes(frame: pd.DataFrame, campaign: Campaign | None) -> list[str]:
    """Numeric grid axes with more than one value (the first axis of each zipped group)."""
    if campaign is not None:
        keys = [group[0].key for group in campaign.grid.groups]
    else:
        keys = [c for c in frame.columns if "." in c]
    out = []
    for key in keys:
        if key in frame.columns and pd.api.types.is_numeric_dtype(frame[key]) and frame[key].nunique() > 1:
            out.append(key)
    return out


def _signal_unit(name: str, channels: Mapping[str, Mapping[str, Any]], campaign: Campaign | None) -> str:
    """Unit of a logged signal: the log's own record, else the rig's signal of that name, else (a
    controlled output that is no rig output, i.e. the difference quotient (2.34) of one) the rig
    output's unit per second."""
    unit = str(channels.get(name, {}).get("unit") or "")
    if unit or campaign is None:
        return unit
    signals = {s.name: s.unit for s in (*campaign.rig_info.inputs, *campaign.rig_info.outputs)}
    if name in signals:
        return signals[name]
    outputs = campaign.rig_info.outputs
    return f"{outputs[0].unit}/s" if outputs and outputs[0].unit else ""


def _units(frame: pd.DataFrame, directory: Path, campaign: Campaign | None) -> dict[str, str]:
    """Units of the gains and metrics, from the first readable log's channel record."""
    from labrunner.logs import read_metadata

    for path in frame["log_path"].dropna().head(5):
        try:
            channels = read_metadata(directory / path).get("channels", {})
        except (LabrunnerError, OSError, ValueError):
            continue
        errors = [c for c, i in channels.items() if i.get("role") == "error"]
        inputs = [c for c, i in channels.items() if i.get("role") == "input"]
        e_unit = _signal_unit(errors[0][2:], channels, campaign) if errors else ""
        u_unit = _signal_unit(inputs[0], channels, campaign) if inputs else ""
        units = {
            "rms_error": e_unit,
            "max_abs_input": u_unit,
            "input_energy": f"{u_unit}²" if u_unit else "",
            "max_current": "A",
        }
        kind = campaign.base.get("controller", {}).get("kind") if campaign is not None else None
        order = {"mfc1": 1, "mfc1-ff": 1, "mfc2": 2}.get(str(kind))
        if order and e_unit and u_unit:
            units.update(gain_units(order, e_unit, u_unit))
            output = campaign.base.get("controller", {}).get("output")
            units["controller.gamma"] = GAMMA_UNITS.get(output, units["controller.gamma"])
        return units
    return {}


def counts(frame: pd.DataFrame) -> dict[str, Any]:
    """Points, finished runs, points per outcome word (:data:`~labrunner.campaign.progress.OUTCOMES`),
    and ``oscillating``: completed runs the oscillation detector flags (observed unstable)."""
    found = frame["outcome"].value_counts()
    outcomes = {w: int(found.get(w, 0)) for w in OUTCOMES}
    return {
        "points": int(len(frame)),
        "runs": sum(outcomes[w] for w in FINISHED),
        "outcomes": outcomes,
        "oscillating": int((agreement_mod.observed_outcome(frame) == "oscillating").sum()),
    }


def chosen_runs(frame: pd.DataFrame) -> dict[str, pd.Series]:
    """Best and worst completed run (by RMS of e) and the first aborted run (in grid order)."""
    done = frame[(frame["outcome"] == "completed") & np.isfinite(frame["rms_error"].to_numpy(dtype=float))]
    out: dict[str, pd.Series] = {}
    if not done.empty:
        out["best"] = done.loc[done["rms_error"].idxmin()]
        out["worst completed"] = done.loc[done["rms_error"].idxmax()]
    aborted = frame[frame["outcome"] == "aborted"]
    if not aborted.empty:
        out["first aborted"] = aborted.loc[aborted["seq"].idxmin()]
    return out


def plot_selection(frame: pd.DataFrame, plot: Sequence[str]) -> list[str]:
    """Point ids the ``--plot`` words choose: ``all``, an outcome word (``aborted``, ...) or ids."""
    ids: list[str] = []
    known = set(frame["id"])
    for word in plot:
        if word == "all":
            chosen = frame["id"]
        elif word in OUTCOMES:
            chosen = frame.loc[frame["outcome"] == word, "id"]
        elif word in known:
            chosen = [word]
        else:
            raise InvalidParameter(
                "--plot", f"must be 'all', an outcome ({', '.join(FINISHED)}) or a point id, got {word!r}"
            )
        ids += [i for i in chosen if i not in ids]
    return ids


def analyse(
    directory: str | Path,
    out: str | Path | None = None,
    *,
    workers: int | None = None,
    margin: float = 0.1,
    error: str = "e",
    recompute: bool = False,
    plot: Sequence[str] = (),
    stream: TextIO | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Analyse a campaign directory; write the table, figures and ``index.html`` under ``out``.

    ``error="e_hat"`` ranks runs and draws the RMS map by the delayed, filtered error ê of paper 2
    (logged as ``e_hat_<output>``) instead of e; the table always holds both. The metrics come
    from the ledger; ``recompute`` reads every log and computes them again. ``plot`` chooses runs
    to draw besides the best, worst and first aborted ones (see :func:`plot_selection`). Progress
    goes to ``stream`` (default stderr: a bar on a terminal, else plain lines; ``progress=False``: none).
    """
    from labrunner.campaign.ledger import Ledger
    from labrunner.campaign.progress import Steps

    if error not in ("e", "e_hat"):
        raise InvalidParameter("error", f"must be 'e' or 'e_hat', got {error!r}")
    directory = Path(directory)
    out = Path(out) if out is not None else directory / "report"
    steps = Steps(f"analyse {directory}", 4, stream=stream) if progress else None

    def step(name: str, more: int = 0) -> None:
        if steps is not None:
            steps.begin(name, more)

    def advance(n: int = 1) -> None:
        if steps is not None:
            steps.advance(n)

    step("reading the ledger")
    with Ledger.open_readonly(directory) as ledger:
        rows = [dict(r) for r in ledger.rows()]
        meta = ledger.meta()
        quarantine = [dict(r) for r in ledger.quarantined()]
    campaign, note = load_campaign(meta, directory)
    rig_units = (
        {s.name: s.unit for s in (*campaign.rig_info.inputs, *campaign.rig_info.outputs)}
        if campaign is not None
        else {}
    )
    rig_limits = {s.name: (s.lo, s.hi) for s in campaign.rig_info.inputs} if campaign is not None else {}
    advance()
    step("metrics table")
    built = table_mod.build_table(
        rows,
        directory,
        cache=table_mod.read_cache(out),
        workers=workers,
        units=rig_units,
        limits=rig_limits,
        recompute=recompute,
        tick=advance,
        announce=lambda n: step(f"metrics table, reading {n} logs", n),
    )
    frame = built.frame
    problems = built.problems + table_mod.quarantine_problems(quarantine, directory)
    if error == "e_hat":
        if not frame.get("rms_error_hat", pd.Series(dtype=float)).notna().any():
            raise InvalidParameter("error", "e_hat: the runs of this campaign log no ê (e_hat_<output>)")
        frame = frame.assign(rms_error=frame["rms_error_hat"])
    ctx = Context(
        directory,
        out,
        campaign,
        note,
        varying_axes(frame, campaign),
        _units(frame, directory, campaign),
        "ê" if error == "e_hat" else "e",
    )
    chosen = chosen_runs(frame)
    extra = plot_selection(frame, plot)
    ids = list(dict.fromkeys([*(row["id"] for row in chosen.values()), *extra]))
    # Two cores: the run plots (the usual few; many, --plot all, are drawn here with progress) are
    # drawn in a child forked now, the second half of the maps in one forked once their overlays
    # are computed; this process draws the rest and writes the tables meanwhile.
    concurrent = (workers or os.cpu_count() or 1) > 1
    if concurrent:
        figures.warm_text()  # fonts and mathtext loaded once, for all processes
    children: list[Background] = []
    if concurrent and 0 < len(ids) <= BACKGROUND_PLOTS and figures.plots_to_draw(frame, ids, ctx):
        children.append(Background(lambda: figures.draw_runs(frame, ids, ctx)))
    drawing = children[0] if children else None
    try:
        csv, parquet = table_mod.write_table(built.frame, out, directory)
        advance()
        step("maps")
        theories = Theories(campaign)
        jobs = figures.map_jobs(frame, ctx, theories)
        half = len(jobs) // 2 if concurrent else 0
        if half:
            children.append(Background(lambda: figures.draw(jobs[-half:])))
        maps = figures.draw(jobs[: len(jobs) - half]) + (children[-1].result() if half else [])
        advance()
        agree = agreement_mod.agreement(frame, theories, gains_of=theories.gains, margin=margin)
        sections, guided = [], None
        if campaign is not None and campaign.guided is not None:  # the walk and its step counts
            from labrunner.campaign import guided_report

            sections, guided = guided_report.sections(campaign, rows, out)
        step("run plots", len(ids))
        if drawing is not None:
            plots = drawing.result()
            advance(len(ids))
        else:
            plots = figures.draw_runs(frame, ids, ctx, tick=advance)
    finally:
        for child in children:
            child.close()
    step("report")
    summary = {
        **counts(frame),
        "best": _best(frame),
        "maps": [str(p) for p, _ in maps],
        "run_plots": [str(p) for p in plots.values()],
        "agreement": agree,
        "problems": problems,
        "metrics": [str(csv), str(parquet)],
        "logs_read": built.n_read,
    }
    if guided is not None:
        summary["guided"] = guided
    summary["report"] = str(
        campaign_report.campaign_report(frame, ctx, summary, maps, chosen, plots, theories, extra=sections)
    )
    advance()
    if steps is not None:
        steps.close()
    return summary


def _best(frame: pd.DataFrame) -> dict[str, Any] | None:
    best = chosen_runs(frame).get("best")
    if best is None:
        return None
    params = {k: _plain(best[k]) for k in frame.columns if "." in k and pd.notna(best[k])}
    return {
        "id": best["id"],
        "params": params,
        "rms": float(best["rms_error"]),
        "input_energy": float(best["input_energy"]),
    }


def _plain(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value
