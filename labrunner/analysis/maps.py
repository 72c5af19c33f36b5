"""Heat maps of a metric over two grid axes and line plots over one, with the thesis's markers.

Markers as in the thesis (Figs. 3.10, 3.14): an aborted run is a red triangle, a run whose input
was too small to move the load (no-motion) a white circle, a completed run a black cross (with a
thin white halo, so that it stays visible on the dark end of the colour map). Failed
runs (an exception, not the plant) get a grey square, completed runs the oscillation detector
flags an orange diamond. Cells of aborted, oscillating and failed runs are left uncoloured: their
metric covers only part of the run, or a limit cycle, and would mislead the colour scale.

A map whose cells are too small for a marker each (:func:`markers_fit`: the 40 × 25 and 10 × 10
maps keep them; a 1000 × 1000 map would be hatched over by them) shows the outcomes as a raster
instead: completed and no-motion cells in their metric's colour (no-motion ones under a white
veil), aborted (dark red), oscillating (orange) and failed (dark grey) cells flat, with a legend of
patches (:func:`draw_outcome_cells`). Markers and raster are drawn from the same cells
(:class:`~.map_data.Grid`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import matplotlib
import numpy as np
from matplotlib import colors, patheffects, ticker
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from labrunner.analysis.map_data import COLOURED, NO_RUN, OUTCOMES, Axis, Grid, Points, cell_edges
from labrunner.analysis.overlays import OverlayLine

#: Marker style per run outcome (in :data:`~.map_data.OUTCOMES` order): (label, marker, face
#: colour, edge colour).
MARKERS = {
    "aborted": ("aborted by the safety routine", "^", "red", "darkred"),
    "no-motion": ("no-motion (input too small)", "o", "white", "black"),
    "completed": ("completed", "x", "black", "black"),
    "failed": ("failed (error)", "s", "grey", "black"),
    "oscillating": ("oscillating / at an input limit (detector)", "D", "orange", "darkorange"),
}

assert tuple(MARKERS) == OUTCOMES
#: A marker's area [pt²] (matplotlib's ``s``): √28 ≈ 5.3 pt wide.
MARKER_AREA = 28
#: A map keeps its markers while its cells are at least this many marker widths wide and high:
#: 9.4 × 12.4 pt cells of the 40 × 25 maps (1.8 widths), then a margin of colour shows around
#: each; 7.3 pt cells of a 50-wide map (1.4) would be mostly marker, a 1000 × 1000 map's 0.37 pt
#: cells hidden under them.
MARKER_CELL = 1.5
#: Colour of a cell in the raster of a dense map, per outcome code (None: the metric's colour).
CELL_COLOURS = {
    "aborted": "darkred",  # the triangles' edge: the red bounds stay visible on it
    "no-motion": (1.0, 1.0, 1.0, 0.55),  # a white veil over the metric's colour
    "completed": None,
    "failed": "dimgrey",
    "oscillating": "orange",
}
_UNCOLOURED = "#d9d9d9"  # cells without a colour of their metric (and in a raster: without a run)

#: A thin white halo keeps the black crosses visible on the dark end of the colour map.
_HALO = [patheffects.withStroke(linewidth=2.4, foreground="white")]


def colour_norm(z: np.ndarray, log: bool | None = None) -> colors.Normalize:
    """Log colour scale when the finite positive values span more than two decades (or if asked).

    A linear scale is robust to outliers: when the values above the 95th percentile stretch the
    range to more than three times the span of the rest, the scale ends at that percentile (the
    colour bar then extends to the outliers), so that a few saturated runs do not wash out the map.
    """
    finite = z[np.isfinite(z)]
    positive = finite[finite > 0]
    if log is None:
        log = positive.size > 0 and positive.size == finite.size and positive.max() / positive.min() > 100
    if log and positive.size:
        return colors.LogNorm(vmin=positive.min(), vmax=positive.max())
    if finite.size:
        lo, top = float(finite.min()), float(np.percentile(finite, 95))
        hi = top if finite.size >= 20 and top > lo and finite.max() - lo > 3 * (top - lo) else float(finite.max())
        return colors.Normalize(vmin=lo, vmax=hi)
    return colors.Normalize(vmin=0.0, vmax=1.0)


#: The thesis's symbols in labels and legends as math type: gains with upright subscripts
#: ($k_\mathrm{p}$, ISO 80000-2), Greek letters in the math font.
MATH = {
    "k_p": r"$k_\mathrm{p}$",
    "k_d": r"$k_\mathrm{d}$",
    "ω_c": r"$\omega_\mathrm{c}$",
    "f_s": r"$f_\mathrm{s}$",
    "δ_t": r"$\delta_t$",
    "γ": r"$\gamma$",
    "ρ": r"$\rho$",
    "α": r"$\alpha$",
    "β": r"$\beta$",
    "δ": r"$\delta$",
    "ê": r"$\hat{e}$",
}


def math_text(text: str) -> str:
    """``text`` with the symbols of :data:`MATH` in math type (a label, title or legend entry)."""
    out, i = [], 0
    while i < len(text):
        hit = next((s for s in MATH if text.startswith(s, i) and _alone(text, i, len(s))), None)
        out.append(MATH[hit] if hit else text[i])
        i += len(hit) if hit else 1
    return "".join(out)


def _alone(text: str, i: int, n: int) -> bool:
    """Whether ``text[i:i + n]`` is a symbol, not part of a word (the k_p of ``k_p_max``: no)."""
    before = text[i - 1] if i else " "
    after = text[i + n] if i + n < len(text) else " "
    return not (before.isalnum() or before == "_") and not (after.isalnum() or after == "_")


def draw_markers(ax: Axes, x: np.ndarray, y: np.ndarray, outcome: np.ndarray) -> None:
    """Scatter one marker per run at (``x``, ``y``), styled by its outcome code; each outcome one
    labelled collection."""
    for code, (label, marker, face, edge) in enumerate(MARKERS.values()):
        mine = outcome == code
        if not mine.any():
            continue
        style = {"c": face, "edgecolors": edge} if marker != "x" else {"c": face, "path_effects": _HALO}
        ax.scatter(x[mine], y[mine], marker=marker, s=MARKER_AREA, linewidths=1.0, label=label, zorder=4, **style)


def markers_fit(ax: Axes, n_x: int, n_y: int | None = None) -> bool:
    """Whether ``n_x`` (× ``n_y``) cells, at the axes' size on its figure, are large enough for a
    marker each (:data:`MARKER_CELL`); the same at any dpi, cells and markers scaling together."""
    box = ax.get_position()
    width, height = ax.figure.get_size_inches()
    cell = 72.0 * box.width * width / n_x  # [pt]
    if n_y is not None:
        cell = min(cell, 72.0 * box.height * height / n_y)
    return cell >= MARKER_CELL * np.sqrt(MARKER_AREA)


def draw_outcome_cells(ax: Axes, grid: Grid, x_edges: np.ndarray, y_edges: np.ndarray) -> list[Patch]:
    """The raster of a dense map: the cells of the outcomes in :data:`CELL_COLOURS` flat in their
    colour (one mesh of outcome codes, gid "outcomes"). Returns a legend patch for each present
    (and one for cells without a run, which keep the uncoloured grey, if there are any)."""
    flat = [code for code, colour in enumerate(CELL_COLOURS.values()) if colour is not None]
    shown = np.isin(grid.outcome, flat)
    palette = colors.ListedColormap([colour or "none" for colour in CELL_COLOURS.values()])
    ax.pcolormesh(
        x_edges,
        y_edges,
        np.ma.masked_array(grid.outcome, mask=~shown),
        cmap=palette,
        norm=colors.BoundaryNorm(np.arange(len(OUTCOMES) + 1) - 0.5, len(OUTCOMES)),
        shading="flat",
        zorder=2,
        gid="outcomes",
    )
    present = np.unique(grid.outcome)
    patches = []
    for code in flat:
        if code in present:
            label = MARKERS[OUTCOMES[code]][0]
            veil = code in COLOURED
            colour = "white" if veil else CELL_COLOURS[OUTCOMES[code]]
            patches.append(Patch(facecolor=colour, edgecolor="grey", label=label + (": pale metric colour" * veil)))
    if NO_RUN in present:
        patches.append(Patch(facecolor=_UNCOLOURED, edgecolor="grey", label="not run"))
    return patches


def draw_heatmap(
    ax: Axes,
    grid: Grid,
    column: str,
    *,
    colour_label: str,
    log_colour: bool | None = None,
    overlays: Sequence[OverlayLine] = (),
) -> list[Patch]:
    """Draw ``column`` over the grid's cells with their outcomes (markers, or a raster where the
    cells are too small: :func:`markers_fit`) and the overlay lines; return the raster's legend
    patches (none with markers: they are labelled artists of the axes)."""
    x, y, z = grid.x, grid.y, grid.images[column]
    x_edges, y_edges = cell_edges(x.values, x.log), cell_edges(y.values, y.log)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad=_UNCOLOURED)
    norm = colour_norm(z, log_colour)
    mesh = ax.pcolormesh(x_edges, y_edges, np.ma.masked_invalid(z), cmap=cmap, norm=norm, shading="flat", zorder=1)
    clipped = bool(np.isfinite(z).any() and np.nanmax(z) > norm.vmax)  # the robust scale cut outliers off
    ax.figure.colorbar(mesh, ax=ax, label=colour_label, extend="max" if clipped else "neither")
    if x.log:
        ax.set_xscale("log")
    if y.log:
        ax.set_yscale("log")
    patches = []
    if markers_fit(ax, len(x.values), len(y.values)):
        draw_markers(ax, *grid.runs())
    else:
        patches = draw_outcome_cells(ax, grid, x_edges, y_edges)
    for line in overlays:
        line.draw(ax)
    ax.set_xlim(*x_edges[[0, -1]])
    ax.set_ylim(*y_edges[[0, -1]])
    ax.set_xlabel(math_text(x.label))
    ax.set_ylabel(math_text(y.label))
    return patches


class InView(ticker.Locator):
    """The locations of ``base`` that lie in the axis's view (to within a tolerance wider than the
    one matplotlib draws ticks by). Matplotlib makes a tick object, formats and measures a label
    for every location a locator returns, and a log locator returns whole decades beyond the view
    that are never drawn: on the 40 × 25 maps ~40 % of their ticks, a quarter of a map's drawing.
    Only for log axes, whose labels do not depend on their neighbours (a linear axis's format
    depends on every location)."""

    def __init__(self, base: ticker.Locator) -> None:
        self.base = base

    def set_axis(self, axis) -> None:
        super().set_axis(axis)
        self.base.set_axis(axis)

    def __call__(self) -> list[float]:
        transform = self.axis.get_transform()
        lo, hi = sorted(transform.transform(np.asarray(self.axis.get_view_interval(), dtype=float)))
        margin = 1e-6 * (hi - lo)
        locs = np.asarray(self.base(), dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = transform.transform(locs)
        return list(locs[(t >= lo - margin) & (t <= hi + margin)])

    def tick_values(self, vmin: float, vmax: float):
        return self.base.tick_values(vmin, vmax)

    def nonsingular(self, v0: float, v1: float):
        return self.base.nonsingular(v0, v1)

    def view_limits(self, vmin: float, vmax: float):
        return self.base.view_limits(vmin, vmax)


def visible_ticks_only(fig: Figure) -> None:
    """Give every log axis of ``fig`` (a map's axes, a log colour bar) :class:`InView` locators;
    the figure draws the same pixels, faster. Call once its scales are set."""
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            if axis.get_scale() == "log" and not isinstance(axis.get_major_locator(), InView):  # shared: once
                axis.set_major_locator(InView(axis.get_major_locator()))
                axis.set_minor_locator(InView(axis.get_minor_locator()))


def map_figure(
    grid: Grid,
    column: str,
    *,
    title: str,
    colour_label: str,
    overlays: Sequence[OverlayLine] = (),
    log_colour: bool | None = None,
    width: float = 7.5,
) -> Figure:
    """A figure ``width`` inches wide with one heat map and a legend of markers (or cell colours)
    and overlays below it; ``title`` "" draws none. Symbols are set in math type (:func:`math_text`).

    Laid out first for a legend of an entry per outcome present and per overlay line, the most
    it will have (the axes' size decides between markers and raster), then for the legend drawn.
    """
    fig = Figure(figsize=(width, width))
    ax = fig.add_subplot()
    ncols = _default_columns(width)
    plot_height = 0.62 * width  # [in] the map's, whatever the title and legend take
    entries = len(set(np.unique(grid.outcome)) - {NO_RUN}) + len(overlays)
    _frame(fig, title, -(-entries // ncols), plot_height)
    patches = draw_heatmap(
        ax, grid, column, colour_label=math_text(colour_label), log_colour=log_colour, overlays=overlays
    )
    title = _wrapped(title, _axes_width(ax))  # centred over the plot, not the colour bar beside it
    if title:
        ax.set_title(math_text(title))
    handles, labels = ax.get_legend_handles_labels()
    handles, labels = [*patches, *handles], [*(p.get_label() for p in patches), *labels]
    ncols, labels = _legend_layout(width, labels, ncols)
    _frame(fig, title, _legend_rows(labels, ncols), plot_height)
    if handles:
        labels = [math_text(t) for t in labels]
        fig.legend(handles, labels, loc="lower center", ncols=ncols, fontsize="small", framealpha=0.9)
    visible_ticks_only(fig)
    return fig


def _text_width(size: str | float, weight: str = "normal") -> Callable[[str], float]:
    """A measure of a text's width [pt] in the font of ``size`` and ``weight``: as plain text,
    ~20 µs a word, where a mathtext measure costs ~4 ms."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    prop, measure = FontProperties(size=size, weight=weight), TextToPath().get_text_width_height_descent
    return lambda text: measure(text, prop, ismath=False)[0]


def _wrapped(title: str, width: float, measure: Callable[[str], float] | None = None) -> str:
    """``title`` broken at spaces into as few lines as fit ``width`` inches in the axes' title
    font (or as ``measure`` [pt] measures), of even length (no word left alone on the last line);
    a word longer than the width keeps a line of its own. Measured as plain text, 5 % to spare
    for the math type of its symbols."""
    if measure is None:
        measure = _text_width(matplotlib.rcParams["axes.titlesize"], matplotlib.rcParams["axes.titleweight"])
    space = measure("a a") - 2 * measure("a")

    def broken(words: list[str], sizes: list[float], limit: float) -> list[str]:
        lines, line, used = [], [], 0.0
        for word, size in zip(words, sizes):
            if line and used + space + size > limit:
                lines.append(" ".join(line))
                line, used = [], 0.0
            used += (space if line else 0.0) + size
            line.append(word)
        return [*lines, " ".join(line)]

    out: list[str] = []
    for paragraph in title.splitlines():
        words = paragraph.split()
        sizes = [measure(word) for word in words]
        limit = 0.95 * width * 72  # [pt]
        count = len(broken(words, sizes, limit))
        low = max(sizes, default=0.0)  # the narrowest limit that keeps ``count`` lines, by bisection
        for _ in range(16):
            middle = (low + limit) / 2
            low, limit = (low, middle) if len(broken(words, sizes, middle)) <= count else (middle, limit)
        out += broken(words, sizes, limit)
    return "\n".join(out)


def _axes_width(ax: Axes) -> float:
    """[in] the width of ``ax`` as laid out (after a colour bar took its share)."""
    return ax.get_position().width * ax.figure.get_size_inches()[0]


def _default_columns(width: float) -> int:
    """Legend columns for a figure ``width`` inches wide before its labels are known: one in a
    paper's column, else two."""
    return 1 if width < 5 else 2


def _legend_layout(width: float, labels: Sequence[str], most: int) -> tuple[int, list[str]]:
    """The legend's columns and labels for a figure ``width`` inches wide: ``most`` columns, fewer
    where the widest label would run off the figure (a bound marked "outside the map" did), and
    in one column labels too long for it wrapped. Spacing as matplotlib's defaults at the
    legend's "small" size."""
    ncols = most
    if not labels:
        return ncols, list(labels)
    measure = _text_width("small")
    em = measure("M")  # ≈ the font size: handle 2 em, pad 0.8 em, column gap 2 em, frame ~1.5 em
    column = max(measure(label) for label in labels) + 2.8 * em
    while ncols > 1 and ncols * column + (ncols - 1) * 2.0 * em + 1.5 * em > width * 72:
        ncols -= 1
    if ncols > 1:
        return ncols, list(labels)
    text = (width * 72 - 4.3 * em) / 72  # [in] what the frame, the handle and its pad leave
    return 1, [_wrapped(label, text, measure) for label in labels]


def _legend_rows(labels: Sequence[str], ncols: int) -> int:
    """The legend's height in lines: rows of ``ncols`` entries, or every line of a wrapped one."""
    return sum(label.count("\n") + 1 for label in labels) if ncols == 1 else -(-len(labels) // ncols)


def _frame(fig: Figure, title: str, rows: int, plot_height: float) -> None:
    """Fixed margins from the title's lines and the legend's rows — no layout engine, which
    would measure every text box of the figure (≈ 2 s of a 1000-run analysis) — and the figure's
    height from them and ``plot_height`` [in], the axes' (so that a long legend in a paper's
    column makes the figure taller, not the plot smaller). Sizes in lines of the text size
    (rcParams: a paper's column draws smaller text)."""
    import matplotlib

    line = matplotlib.rcParams["font.size"] / 72 * 1.58  # [in] a line of text, as at 10 pt: 0.22 in
    top = 0.1 + line * 0.7 + (line * (title.count("\n") + 1) if title else 0.0)  # [in] title lines
    bottom = 2.5 * line + (line * rows + 0.15 if rows else 0.0)  # [in] tick and axis labels, legend rows
    width = fig.get_size_inches()[0]
    height = plot_height + top + bottom
    fig.set_size_inches(width, height)
    fig.subplots_adjust(
        left=3.9 * line / width, right=1 - 0.2 / width, top=1 - top / height, bottom=bottom / height, hspace=0.12
    )


def sweep_figure(
    points: Points,
    x: Axis,
    columns: Sequence[tuple[str, str]],
    *,
    title: str,
    overlays: Sequence[OverlayLine] = (),
    width: float = 7.5,
    joined: bool = True,
) -> Figure:
    """1-D sweep, ``width`` inches wide: one panel per (column, label) over the axis, run markers
    by outcome (an aborted run's marker at its ``<column>_until_abort`` value, the metric of its
    run up to the abort). Where the runs lie too close for a marker each (:func:`markers_fit`),
    the line alone, labelled, shows the completed runs, and markers the others; ``title`` "":
    none. ``joined`` False: markers only (runs of a zipped sweep whose other gain is no function
    of the swept one, which a line sorted along the axis would join across)."""
    plot_height = (2.6 * len(columns) - 0.9) * min(1.0, width / 6.0)  # [in] the panels'
    fig = Figure(figsize=(width, plot_height + 2.0))
    axes = fig.subplots(len(columns), 1, sharex=True, squeeze=False)[:, 0]
    ordered = points.where(np.argsort(points[x.key], kind="quicksort"))  # as pandas' sort_values
    ok = ordered.where(ordered.coloured())
    dense = joined and not markers_fit(axes[0], max(len(np.unique(ordered[x.key])), 1))
    completed = OUTCOMES.index("completed")
    outcome = np.where(ordered.outcome == completed, NO_RUN, ordered.outcome) if dense else ordered.outcome
    for ax, (column, label) in zip(axes, columns):
        line = MARKERS["completed"][0] if dense else None
        if joined:
            ax.plot(ok[x.key], ok[column], color="tab:blue", linewidth=1.2, zorder=2, label=line)
        until = f"{column}_until_abort"
        value = ordered[column]
        if until in ordered:
            value = np.where(np.isnan(value), ordered[until], value)
        shown = np.isfinite(value)
        draw_markers(ax, ordered[x.key][shown], value[shown], outcome[shown])
        positive = ok[column]
        positive = positive[np.isfinite(positive) & (positive > 0)]
        if positive.size and positive.max() / positive.min() > 100:
            ax.set_yscale("log")
        for line in overlays:
            line.draw(ax)
        ax.set_ylabel(math_text(label))
        ax.grid(True, which="both", alpha=0.3)
    if x.log:
        axes[-1].set_xscale("log")
    axes[-1].set_xlabel(math_text(x.label))
    title = _wrapped(title, _axes_width(axes[0]))
    if title:
        axes[0].set_title(math_text(title))
    handles, labels = axes[0].get_legend_handles_labels()
    ncols, labels = _legend_layout(width, labels, _default_columns(width) + (width >= 5))
    _frame(fig, title, _legend_rows(labels, ncols), plot_height)
    if handles:
        fig.legend(handles, [math_text(t) for t in labels], loc="lower center", ncols=ncols, fontsize="small")
    visible_ticks_only(fig)
    return fig
