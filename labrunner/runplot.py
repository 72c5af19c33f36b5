"""The figure of one run, drawn like the thesis's Figs. 3.12 and 3.20.

Stacked panels over a shared time axis: the controlled outputs with their references (dashed,
same colour), the inputs, the estimates (one panel per quantity: ``f_hat_*``, ``e_hat_*``,
``de_hat_*``), then signals of unknown role. An aborted run gets a dotted red
line at the abort time on every panel, the rest of the run (up to its planned ``run.duration``
where the log records it: the engine ends the signals at the abort) greyed out, and a cross on
each input at that instant; the title says what happened (monitor, value, threshold). A run
aborted early is drawn zoomed to its abort, under a strip showing the whole planned run. Used by
``labrunner plot`` and by the analysis report (pass a figure or sub-figure to draw into).
No pyplot: the figure is a plain :class:`matplotlib.figure.Figure`, safe in worker threads.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure, SubFigure

from labrunner.logs import RunLog, read_run

_TEX = {"omega": r"\Omega", "theta": r"\theta", "phi": r"\varphi", "psi": r"\psi", "gamma": r"\gamma"}
_ABORT = "C3"


def signal_label(name: str) -> str:
    """``ref_omega`` → Ω_r, ``theta`` → θ, ``f_hat_omega`` → f̂_Ω; other names unchanged."""
    if name.startswith("ref_") and name[4:] in _TEX:
        return f"${_TEX[name[4:]]}_r$"
    estimate, _, output = name.partition("_hat_")
    if output in _TEX and estimate.isalpha():
        return rf"$\hat{{{estimate}}}_{{{_TEX[output]}}}$"
    return f"${_TEX[name]}$" if name in _TEX else name


def signal_roles(log: RunLog) -> dict[str, list[str]]:
    roles: dict[str, list[str]] = {}
    for name in log.signals:
        roles.setdefault(log.channels.get(name, {}).get("role", "signal"), []).append(name)
    return roles


def _panels(log: RunLog) -> list[tuple[str, list[tuple[str, str]]]]:
    """``[(panel title, [(signal, "-" or "--"), ...]), ...]``, empty panels left out."""
    roles, names = signal_roles(log), set(log.signals)
    tracked = [(ref[4:], ref) for ref in roles.get("reference", []) if ref[4:] in names]
    if tracked:
        outputs = [item for y, ref in tracked for item in ((y, "-"), (ref, "--"))]
    else:
        outputs = [(n, "-") for role in ("controlled", "output", "reference", "signal") for n in roles.get(role, [])]
    drawn = {n for n, _ in outputs}
    kinds: dict[str, list[tuple[str, str]]] = {}  # f̂, ê, ê̇ differ in unit and scale: one panel each
    for name in roles.get("estimate", []):
        kinds.setdefault(name.partition("_hat")[0], []).append((name, "-"))
    panels = [
        ("outputs", outputs),
        ("inputs", [(n, "-") for n in roles.get("input", [])]),
        *(("estimates", lines) for lines in kinds.values()),
        ("signals", [(n, "-") for n in roles.get("signal", []) if n not in drawn]),  # role unknown
    ]
    return [(title, lines) for title, lines in panels if lines]


#: The gains in a title, in math type as the maps set them.
_GAINS = {"gamma": r"$\gamma$", "k_p": r"$k_\mathrm{p}$", "k_d": r"$k_\mathrm{d}$"}


def _symbol(key: str) -> str:
    name = key.rsplit(".", 1)[-1]
    return _GAINS.get(name, name)


def _title(log: RunLog) -> str:
    """Which run (its id and grid values) over how it ended: two lines, so that both fit the width."""
    run = log.metadata.get("run", {})
    head = str(run.get("point_id") or run.get("name") or "run")
    params = log.metadata.get("parameters") or {}
    if params:  # the grid values that make this run what it is, e.g. "(γ = 108.6, k_p = 50)", in math type
        shown = ", ".join(
            f"{_symbol(k)} = {v:.4g}" if is_number(v) else f"{_symbol(k)} = {v}" for k, v in params.items()
        )
        head = f"{head} ({shown})"
    out: dict[str, Any] | None = log.outcome
    if out is None:
        return f"{head}\ntorn log, no outcome ({log.n_samples} samples salvaged)"
    status = str(out.get("status", "?"))
    if status == "aborted":
        value, threshold = out.get("value"), out.get("threshold")
        detail = f" ({value:.4g} vs. limit {threshold:.4g})" if is_number(value) and is_number(threshold) else ""
        when = f" at t = {out['time']:.3f} s" if is_number(out.get("time")) else ""
        return f"{head}\naborted by {out.get('monitor', '?')}{when}{detail}"
    if status == "failed" and out.get("message"):
        return f"{head}\nfailed: {out['message']}"
    return f"{head}\n{status}"


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def common_unit(log: RunLog, names: list[str]) -> tuple[str, float]:
    """The panel's unit label and the factor its data is drawn with (air gaps in mm, as the
    papers show them: metres below 0.1 m are drawn in millimetres)."""
    units = [u for u in dict.fromkeys(log.channels.get(n, {}).get("unit", "") for n in names) if u]
    if units == ["m"] and np.nanmax(np.abs([log.signal(n) for n in names]), initial=0.0) < 0.1:
        return "mm", 1e3
    return ", ".join(units), 1.0


def _draw(ax: Axes, log: RunLog, lines: list[tuple[str, str]], t: np.ndarray, scale: float, lw: float = 1.0) -> None:
    """The panel's lines: a reference dashed, in the colour of the signal it is the reference of."""
    colours: dict[str, str] = {}
    for name, style in lines:
        base = name[4:] if style == "--" else name
        colour = colours.setdefault(base, f"C{len(colours) % 10}")
        ax.plot(
            t,
            scale * log.signal(name),
            style,
            color=colour,
            lw=lw if style == "-" else 1.3 * lw,
            label=signal_label(name),
        )


def _abort_window(log: RunLog, t: np.ndarray) -> tuple[float | None, float, float]:
    """(abort time or None, end of the planned run, end of the panels' time axis) [s].

    An aborted run's signals end at the abort; its axis is the planned run (``run.duration``).
    When the run reached less than two thirds of it, the panels zoom to the abort (with a margin)
    and a strip above them shows the whole planned time."""
    out = log.outcome or {}
    t_abort = out.get("time") if out.get("status") == "aborted" and is_number(out.get("time")) else None
    t_end = float(t[-1]) if len(t) else 0.0
    planned = log.metadata.get("run", {}).get("duration")
    if t_abort is None:
        return None, t_end, t_end
    if is_number(planned):
        t_end = max(t_end, float(planned))  # an aborted run on the axis of the run it should have been
    reached = max(float(t_abort), float(t[-1]) if len(t) else 0.0)
    if t_end <= 1.5 * reached:
        return float(t_abort), t_end, t_end
    step = 1.0 / log.fs if is_number(log.fs) and log.fs > 0 else 0.0
    return float(t_abort), t_end, min(t_end, reached + max(0.1 * reached, 10 * step))


def _context(
    ax: Axes, log: RunLog, lines: list[tuple[str, str]], t: np.ndarray, t_abort: float, t_end: float, zoom_end: float
) -> None:
    """The whole planned run in one strip: the outputs, the part never reached greyed out, the
    abort, and the window the panels below show."""
    unit, scale = common_unit(log, [n for n, _ in lines])
    _draw(ax, log, lines, t, scale, 0.8)
    ax.axvspan(t_abort, t_end, color="0.9", zorder=0)
    ax.axvline(t_abort, color=_ABORT, ls=":", lw=1.5)
    ax.axvspan(0.0, zoom_end, fill=False, edgecolor="0.3", lw=1.0, ls="--", zorder=3)
    ax.set_xlim(0.0, t_end)
    ax.set_yticks([])
    ax.set_ylabel(f"[{unit}]" if unit else "")
    planned = f"planned run, 0 – {t_end:.4g} s: aborted at {t_abort:.4g} s ({t_abort / t_end:.0%})"
    below = f"below: 0 – {zoom_end:.3g} s"
    figure = ax.figure
    while not hasattr(figure, "get_size_inches"):  # drawn into a sub-figure: its root's width
        figure = figure.figure
    narrow = figure.get_size_inches()[0] < 5  # a paper's column: two lines
    ax.set_title(f"{planned}{chr(10) if narrow else '; '}{below}", fontsize="small", loc="left")


def plot_run(
    log: RunLog | str | os.PathLike[str], fig: Figure | SubFigure | None = None, *, width: float = 7.5
) -> Figure | SubFigure:
    """Draw a run (a :class:`RunLog` or the path of its MCAP) into ``fig`` (a new one ``width``
    inches wide if None: 3.5 for a paper's column, 7.16 across its page).

    ``fig.axes`` are the panels, top to bottom; an aborted run that ended early has one more, last
    in the list and drawn above the panels: the planned run as context (:func:`_abort_window`)."""
    if not isinstance(log, RunLog):
        log = read_run(log)
    panels = _panels(log) or [("signals", [(n, "-") for n in log.signals])]
    t = log.t
    t_abort, t_end, zoom_end = _abort_window(log, t)
    context = t_abort is not None and zoom_end < t_end
    heights = [1.8] * len(panels) + ([0.9] if context else [])
    if fig is None:
        height = 1.4 + sum(heights) + (0.4 if context else 0.0)
        fig = Figure(figsize=(width, height * min(1.0, width / 6.0)))
    grid = fig.add_gridspec(len(heights), 1, height_ratios=[heights[-1], *heights[:-1]] if context else heights)
    rows = range(1, len(heights)) if context else range(len(heights))
    axes: list[Axes] = []
    for row in rows:
        axes.append(fig.add_subplot(grid[row], sharex=axes[0] if axes else None))
    for ax in axes[:-1]:
        ax.tick_params(labelbottom=False)
    for ax, (title, lines) in zip(axes, panels):
        unit, scale = common_unit(log, [n for n, _ in lines])
        _draw(ax, log, lines, t, scale)
        if t_abort is not None and title == "inputs" and len(t):
            k = min(int(np.searchsorted(t, t_abort)), len(t) - 1)
            for line in list(ax.get_lines()):
                ax.plot([t[k]], [line.get_ydata()[k]], "x", color=_ABORT, ms=8, mew=2)
        ax.set_ylabel(f"{title} [{unit}]" if unit else title)
        ax.grid(True, lw=0.4, alpha=0.6)
        ax.legend(
            loc="upper left" if t_abort is not None else "upper right",  # away from where an aborted run ends
            fontsize="small",
            ncols=min(4, len(lines)),
            framealpha=0.8,
        )
        if t_abort is not None:
            ax.axvline(t_abort, color=_ABORT, ls=":", lw=1.5)
            ax.axvspan(t_abort, max(t_end, t_abort), color="0.9", zorder=0)
    axes[-1].set_xlabel("t [s]")
    if len(t) and zoom_end > t[0]:
        axes[-1].set_xlim(t[0], zoom_end)
    if context:
        _context(fig.add_subplot(grid[0]), log, panels[0][1], t, t_abort, t_end, zoom_end)
    fig.suptitle(_title(log), fontsize="medium")
    width, height = fig.get_size_inches() if isinstance(fig, Figure) else fig.figure.get_size_inches()
    # fixed margins (no layout engine: it measures every text box, the most of a plot's cost)
    fig.subplots_adjust(
        left=0.9 / width,
        right=1 - 0.15 / width,
        top=1 - (0.9 if context else 0.7) / height,
        bottom=0.5 / height,
        hspace=0.3 if context else 0.12,
    )
    return fig
