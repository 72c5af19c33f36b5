"""The analysis's figures from Python: a campaign's metric map (or sweep plot) and a run's plot,
drawn by the same code as ``labrunner analyse`` and ``labrunner plot``
(:func:`labrunner.analysis.figures.map_jobs`, :func:`labrunner.runplot.plot_run`) and returned as
matplotlib :class:`~matplotlib.figure.Figure` objects to restyle, annotate or save."""

from __future__ import annotations

from typing import TYPE_CHECKING

from labrunner.analysis.png import FigureStyle
from labrunner.errors import InvalidParameter

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from labrunner.results.campaign import CampaignResults
    from labrunner.results.run import RunResults


def campaign_map(
    campaign: CampaignResults, metric: str, *, size: str = "screen", title: bool = True, facet: int = 1
) -> Figure:
    """The map of ``metric`` over the campaign's two grid axes (its sweep plot for one axis), as
    ``analyse`` draws it; ``facet``: which map where the grid has more than two axes (1, 2, ...)."""
    from labrunner.analysis import figures, selection
    from labrunner.analysis.context import Context, Theories

    frame = campaign.table()
    spec, note = selection.load_campaign(campaign.meta, campaign.directory)
    ctx = Context(
        campaign.directory,
        campaign.directory / "report",
        spec,
        note,
        selection.varying_axes(frame, spec),
        selection.table_units(frame, campaign.directory, spec),
    )
    style = FigureStyle(size=size, title=title)
    jobs = figures.map_jobs(frame, ctx, Theories(spec), style)
    if len(jobs) == 1 and jobs[0].figure == "sweep_figure":
        shown = [c for c, _ in jobs[0].args[2]]
        if metric not in shown:
            raise InvalidParameter("metric", f"the sweep plot shows {shown}, not {metric!r}")
        return jobs[0].make()
    maps = [j for j in jobs if j.args[1] == metric]
    if not maps:
        drawn = sorted({j.args[1] for j in jobs})
        raise InvalidParameter("metric", f"no map of {metric!r}; maps: {drawn or 'none (fewer than two grid axes)'}")
    if not 1 <= facet <= len(maps):
        raise InvalidParameter("facet", f"must be in [1, {len(maps)}], got {facet}")
    return maps[facet - 1].make()


def run_figure(run: RunResults, *, size: str = "screen") -> Figure:
    """The run's plot as ``labrunner plot`` draws it, ``size`` wide (screen, column or page)."""
    from labrunner.runplot import plot_run

    style = FigureStyle(size=size)
    with style.drawing():
        return plot_run(run.log, width=style.width)
