"""Draw an analysis's figures, its maps (or sweep plot) and its run plots, on two cores.

``analyse`` forks the drawing child *ahead* (:meth:`~.background.Background.ahead` with
:func:`prepare`): it loads matplotlib, the fonts and the log reader while the analysis imports
pandas and builds the table. The analysis then sends it :func:`draw` with the run plots to draw
and the maps as :class:`FigureJob` (plain data: no table, so this child never loads pandas). The
child forks a second one, which shares what it loaded, for part of the maps, and draws the rest
itself; the analysis itself never loads matplotlib. Without ``fork``, or with one worker,
:func:`draw` runs in the analysis's process and draws everything in turn.
"""

from __future__ import annotations

import gc
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labrunner.analysis import png, run_plots
from labrunner.analysis.background import Background


@dataclass(frozen=True)
class FigureJob:
    """A map or sweep plot to draw: its PNG, its caption, and the :mod:`.maps` function (by name)
    and arguments that make it (a map's :class:`~.map_data.Grid`, a sweep's
    :class:`~.map_data.Points` and :class:`~.map_data.Axis`, overlay lines, text)."""

    path: Path
    caption: str
    figure: str  # "map_figure" or "sweep_figure"
    args: tuple[Any, ...]
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    style: png.FigureStyle = png.FigureStyle()

    def make(self) -> Any:
        """The matplotlib figure, at the style's width and text size."""
        from labrunner.analysis import maps

        with self.style.drawing():
            return getattr(maps, self.figure)(*self.args, **self.kwargs, width=self.style.width)


def prepare() -> None:
    """What drawing needs, loaded ahead (in the drawing child): matplotlib, the maps, the run plots'
    log reader, the fonts."""
    import labrunner.analysis.maps  # noqa: F401

    run_plots.prepare()


def draw_maps(jobs: Sequence[FigureJob]) -> list[tuple[Path, str]]:
    """Draw and save each job's figure: (PNG path, caption) each. Each figure is cleared and
    collected once saved: a figure is a web of reference cycles, which would keep a 1000 × 1000
    map's meshes (~120 MB) while the next map is drawn (two such maps: 362 MB, now 246 MB)."""
    drawn = []
    for job in jobs:
        fig = job.make()
        drawn.append((png.save(fig, job.path, job.style), job.caption))
        fig.clear()
        gc.collect()
    return drawn


def draw(
    plots: Sequence[run_plots.Item],
    jobs: Sequence[FigureJob],
    *,
    split: bool = True,
    tick: Callable[[int], None] | None = None,
    style: png.FigureStyle | None = None,
) -> tuple[list[tuple[Path, str]], dict[str, Path]]:
    """(maps drawn, run plots by id). With ``split``, the last maps are drawn in a forked child, as
    many as make its share of the figures to draw half (a map and a run plot cost about the same,
    ~0.15 s); the run plots (in ``style``) and the other maps here. ``tick`` is told of each run plot."""
    half = (len(run_plots.to_draw(plots, style)) + len(jobs)) // 2 if split else 0
    here = len(jobs) - min(half, len(jobs))
    child = Background(lambda: draw_maps(jobs[here:])) if here < len(jobs) else None
    try:
        drawn = run_plots.draw(plots, tick=tick, style=style)
        maps = draw_maps(jobs[:here]) + (child.result() if child is not None else [])
    finally:
        if child is not None:
            child.close()
    return maps, drawn
