"""``labrunner analyse``: a campaign directory → metrics table, maps, run plots and index.html.

Steps: read the ledger (parameters, outcomes, every run's metrics) and the campaign file it keeps;
build the metrics table from it (:mod:`.table`; logs are read only where the ledger has no
metrics or with ``recompute``); pick the map axes from the grid (γ–k_p and k_p–k_d as in the
thesis, else grid order; further axes become facets); draw RMS and energy maps (or sweep plots)
with the stability overlays that fit (:mod:`.overlays`); plot the best, the worst completed, the
first aborted run and any runs asked for (the only logs read then); compare outcomes with the
theory (:mod:`.agreement`); write the report. Returns the summary that ``--json`` prints. With
more than one worker the figures are drawn in a child forked ahead (:mod:`.drawing`) while this
process writes the tables and compares with the theory.

This module imports nothing heavy: :func:`analyse` forks the drawing child *before* it imports
pandas, so that the child loads matplotlib on the other core meanwhile; this process then hands
it the maps as plain data (:class:`~.drawing.FigureJob`) and never loads matplotlib itself. A
process that runs many analyses (``labrunner reproduce``) loads it once instead
(:func:`prepare_drawing`), for every analysis's child to be forked with it.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from labrunner.analysis import drawing, png, run_plots
from labrunner.analysis.background import Background
from labrunner.errors import InvalidParameter
from labrunner.rigs.device import lawflag

__all__ = ["analyse", "prepare_drawing"]

#: Run plots drawn by the drawing child with the maps (more: in this process, with progress).
BACKGROUND_PLOTS = 8


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
    style: png.FigureStyle | None = None,
) -> dict[str, Any]:
    """Analyse a campaign directory; write the table, figures and ``index.html`` under ``out``.

    ``error="e_hat"`` ranks runs and draws the RMS map by the delayed, filtered error ê of paper 2
    (logged as ``e_hat_<output>``) instead of e; the table always holds both. The metrics come
    from the ledger; ``recompute`` reads every log and computes them again. ``plot`` chooses runs
    to draw besides the best, worst and first aborted ones (see
    :func:`~labrunner.analysis.selection.plot_selection`). Progress
    goes to ``stream`` (default stderr: a bar on a terminal, else plain lines; ``progress=False``: none).
    ``style``: the figures' formats, resolution, size and title (:class:`~.png.FigureStyle`).
    """
    if error not in ("e", "e_hat"):
        raise InvalidParameter("error", f"must be 'e' or 'e_hat', got {error!r}")
    plotter = Background.ahead(drawing.prepare) if _concurrent(workers) else None  # before the imports below
    try:
        return _analyse(
            Path(directory),
            out,
            workers,
            margin,
            error,
            recompute,
            plot,
            stream,
            progress,
            plotter,
            style or png.FigureStyle(),
        )
    finally:
        if plotter is not None:
            plotter.close()


def _concurrent(workers: int | None) -> bool:
    """Whether an analysis with ``workers`` draws its figures in a forked child."""
    return (workers or os.cpu_count() or 1) > 1


def prepare_drawing(workers: int | None) -> None:
    """In a process about to run many analyses (``labrunner reproduce``): load what their drawing
    children load (:func:`.drawing.prepare`: matplotlib, the fonts, the log reader) once, here, so
    that each child is forked with it instead of importing it again (~0.5 CPU-seconds a child).
    Nothing where the analyses draw in this process (one worker)."""
    if _concurrent(workers):
        drawing.prepare()


def _analyse(
    directory: Path,
    out: str | Path | None,
    workers: int | None,
    margin: float,
    error: str,
    recompute: bool,
    plot: Sequence[str],
    stream: TextIO | None,
    progress: bool,
    plotter: Background[dict[str, Path]] | None,
    style: png.FigureStyle,
) -> dict[str, Any]:
    import pandas as pd

    from labrunner import safefs
    from labrunner.analysis import memory, selection, table as table_mod, table_files, table_rows
    from labrunner.campaign.ledger import Ledger, ledger_path
    from labrunner.campaign.progress import Steps

    memory.return_freed_memory()  # after the fork: this process's tables of 10^6 rows, not the drawing child's
    out = Path(out) if out is not None else directory / "report"
    safefs.check_directory(out)  # never write through a link planted at report/ (labrunner.safefs)
    steps = Steps(f"analyse {directory}", 4, stream=stream) if progress else None

    def step(name: str, more: int = 0) -> None:
        if steps is not None:
            steps.begin(name, more)

    def advance(n: int = 1) -> None:
        if steps is not None:
            steps.advance(n)

    step("reading the ledger")
    with Ledger.open_readonly(directory, per_row=False) as ledger:
        meta = ledger.meta()
        quarantine = [dict(r) for r in ledger.quarantined()]
        campaign, note = selection.load_campaign(meta, directory)
        rig_units, rig_limits = selection.rig_signals(campaign)
        advance()
        step("metrics table")
        path = ledger_path(directory)
        with table_rows.verified_chunks(ledger.db, path) as chunks:  # streamed: a chunk of rows at a time
            built = table_mod.build_table(
                chunks,
                directory,
                cache=out / table_files.METRICS_PARQUET,
                workers=workers,
                units=rig_units,
                limits=rig_limits,
                recompute=recompute,
                tick=advance,
                announce=lambda n: step(f"metrics table, reading {n} logs", n),
            )
        guided_rows = [dict(r) for r in ledger.rows()] if campaign is not None and campaign.guided is not None else []
    memory.trim()  # what building the table freed
    frame = built.frame
    problems = built.problems + table_mod.quarantine_problems(quarantine, directory)
    if error == "e_hat":
        if not frame.get("rms_error_hat", pd.Series(dtype=float)).notna().any():
            raise InvalidParameter("error", "e_hat: the runs of this campaign log no ê (e_hat_<output>)")
        frame = frame.assign(rms_error=frame["rms_error_hat"])
    chosen = selection.chosen_runs(frame)
    if guided_rows:  # the procedure's answer leads, as `status` gives it; the lowest RMS is named as such
        chosen = selection.with_procedure_choice(frame, chosen, campaign, guided_rows)
    extra = selection.plot_selection(frame, plot)
    ids = list(dict.fromkeys([*(row["id"] for row in chosen.values()), *extra]))
    chosen_logs = frame.loc[frame["id"].isin(ids), ["id", "log_path"]]  # not a dict of every run's
    plots_of = run_plots.items(dict(zip(chosen_logs["id"], chosen_logs["log_path"])), ids, directory, out)
    from labrunner.analysis import agreement as agreement_mod, figures
    from labrunner.analysis.context import Context, Theories

    ctx = Context(
        directory,
        out,
        campaign,
        note,
        selection.varying_axes(frame, campaign),
        selection.table_units(frame, directory, campaign),
        "ê" if error == "e_hat" else "e",
    )
    theories = Theories(campaign)
    jobs = figures.map_jobs(frame, ctx, theories, style)
    # Two cores: the child forked ahead draws the maps and the usual few run plots from now (with a
    # child of its own: drawing.draw) while this process writes the tables and compares with the
    # theory; many run plots (--plot all) are drawn here, with progress, while it draws the maps.
    many = plotter is not None and len(plots_of) > BACKGROUND_PLOTS
    if plotter is not None and not jobs and not run_plots.to_draw([] if many else plots_of, style):
        plotter.close()  # nothing for it to draw (no map, the plots kept): not waited for
        plotter = many = None
    if plotter is not None:
        plotter.start(functools.partial(drawing.draw, [] if many else plots_of, jobs, style=style))
        memory.trim()  # the pickled maps
    csv, parquet = table_files.write_table(built.frame, out, directory)
    memory.trim()
    advance()
    step("maps")
    agree = agreement_mod.agreement(frame, theories, gains_of=theories.gains, margin=margin)
    memory.trim()
    sections, guided = [], None
    if campaign is not None and campaign.guided is not None:  # the walk and its step counts
        from labrunner.campaign import guided_report

        sections, guided = guided_report.sections(campaign, guided_rows, out)
    if plotter is None:  # one process: the maps, then the run plots with progress
        maps, _ = drawing.draw([], jobs, split=False, style=style)
    elif not many:
        maps, plots = plotter.result()
    del jobs  # the maps' cells (17 MB at 10^6 points): drawn, or the child's to draw
    advance()
    step("run plots", len(plots_of))
    if plotter is None or many:
        plots = run_plots.draw(plots_of, tick=advance, style=style)
    else:
        advance(len(plots_of))
    if many:
        maps, _ = plotter.result()
    step("report")
    from labrunner.analysis import campaign_report  # here: after the drawing child has its work

    summary = {
        **selection.counts(frame),
        "best": selection.best_run(frame),
        "maps": [str(p) for p, _ in maps],
        "run_plots": [str(p) for p in plots.values()],
        "agreement": agree,
        "problems": problems,
        "metrics": [str(csv), str(parquet)],
        "logs_read": built.n_read,
        "law_check": (
            lawflag.summary(zip(frame["id"], frame["law_check"], frame.get("law_arithmetic", [""] * len(frame))))
            if "law_check" in frame
            else None
        ),
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
