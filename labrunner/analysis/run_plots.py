"""The run plots of an analysis (thesis Figs. 3.12, 3.20): ``plots/<id>.png`` drawn from each
chosen run's log by :func:`labrunner.runplot.plot_run`; a plot newer than its log is kept.

Neither this module nor drawing a plot needs pandas: ``analyse`` forks the child that draws them
before it imports pandas and matplotlib itself; the child loads matplotlib meanwhile
(:func:`prepare`) and draws as soon as the table has named the runs."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from labrunner import safefs
from labrunner.analysis import png
from labrunner.errors import LabrunnerError

PLOTS_DIR = "plots"  # run plots, one per point: <out>/plots/<id>.png

#: A plot to draw: (point id, its log, its PNG).
Item = tuple[str, Path, Path]


def plot_path(out: Path, point_id: str) -> Path:
    return out / PLOTS_DIR / f"{point_id}.png"


def items(logs: Mapping[str, object], ids: Sequence[str], directory: Path, out: Path) -> list[Item]:
    """The plots of ``ids`` (once each, in order) that have a log (``logs``: id → path in ``directory``)."""
    return [
        (point_id, directory / rel, plot_path(out, point_id))
        for point_id in dict.fromkeys(ids)
        if isinstance(rel := logs.get(point_id), str)
    ]


def _kept(log: Path, plot: Path, style: png.FigureStyle | None) -> bool:
    """Whether ``plot`` in each of the style's formats is newer than its ``log`` (then it is not drawn again)."""
    formats = dict.fromkeys(["png", *(style or png.FigureStyle()).formats])
    files = [plot.with_suffix(f".{fmt}") for fmt in formats]
    return all(f.is_file() and f.stat().st_mtime_ns >= log.stat().st_mtime_ns for f in files)


def to_draw(plots: Sequence[Item], style: png.FigureStyle | None = None) -> list[str]:
    """The ids among ``plots`` whose plot :func:`draw` would draw (not kept, a log to draw it from)."""
    todo = []
    for point_id, log, plot in plots:
        try:
            if not _kept(log, plot, style):
                todo.append(point_id)
        except OSError:
            pass
    return todo


def prepare() -> None:
    """What drawing needs, loaded ahead (in the child forked for the plots)."""
    import labrunner.runplot  # noqa: F401 - matplotlib and the log reader

    png.warm_text()


def draw(
    plots: Sequence[Item], tick: Callable[[int], None] | None = None, style: png.FigureStyle | None = None
) -> dict[str, Path]:
    """Draw each plot not kept, in ``style``; the PNG of every plot there is, by id (unreadable logs are skipped)."""
    out: dict[str, Path] = {}
    style = style or png.FigureStyle()
    for point_id, log, plot in plots:
        try:
            if not _kept(log, plot, style):
                from labrunner import run_identity
                from labrunner.logs import read_run
                from labrunner.runplot import plot_run  # matplotlib: only when a plot is drawn

                run = read_run(log)
                run_identity.check(run.metadata, point_id, log)  # a swapped log would plot another run
                safefs.mkdir(plot.parent, parents=True)
                with style.drawing():
                    fig = plot_run(run, width=style.width)
                png.save(fig, plot, style)
            out[point_id] = plot
        except (LabrunnerError, OSError, ValueError, KeyError):
            pass
        if tick:
            tick(1)
    return out
