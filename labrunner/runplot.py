"""The figure of one run, drawn like the thesis's Figs. 3.12 and 3.20.

Stacked panels over a shared time axis: the controlled outputs with their references (dashed,
same colour), the inputs, the estimates (one panel per quantity: ``f_hat_*``, ``e_hat_*``,
``de_hat_*``), then signals of unknown role. An aborted run gets a dotted red
line at the abort time on every panel, the rest of the run (up to its planned ``run.duration``
where the log records it: the engine ends the signals at the abort) greyed out, and a cross on
each input at that instant; the title says what happened (monitor, value, threshold). Used by
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


def _label(name: str) -> str:
    """``ref_omega`` → Ω_r, ``theta`` → θ, ``f_hat_omega`` → f̂_Ω; other names unchanged."""
    if name.startswith("ref_") and name[4:] in _TEX:
        return f"${_TEX[name[4:]]}_r$"
    estimate, _, output = name.partition("_hat_")
    if output in _TEX and estimate.isalpha():
        return rf"$\hat{{{estimate}}}_{{{_TEX[output]}}}$"
    return f"${_TEX[name]}$" if name in _TEX else name


def _roles(log: RunLog) -> dict[str, list[str]]:
    roles: dict[str, list[str]] = {}
    for name in log.signals:
        roles.setdefault(log.channels.get(name, {}).get("role", "signal"), []).append(name)
    return roles


def _panels(log: RunLog) -> list[tuple[str, list[tuple[str, str]]]]:
    """``[(panel title, [(signal, "-" or "--"), ...]), ...]``, empty panels left out."""
    roles, names = _roles(log), set(log.signals)
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


def _title(log: RunLog) -> str:
    """Which run (its id and grid values) over how it ended: two lines, so that both fit the width."""
    run = log.metadata.get("run", {})
    head = str(run.get("point_id") or run.get("name") or "run")
    params = log.metadata.get("parameters") or {}
    if params:  # the grid values that make this run what it is, e.g. "(gamma = 108.6, k_p = 50)"
        shown = ", ".join(f"{k.rsplit('.', 1)[-1]} = {v:.4g}" if _number(v) else f"{k.rsplit('.', 1)[-1]} = {v}"
                          for k, v in params.items())
        head = f"{head} ({shown})"
    out: dict[str, Any] | None = log.outcome
    if out is None:
        return f"{head}\ntorn log, no outcome ({log.n_samples} samples salvaged)"
    status = str(out.get("status", "?"))
    if status == "aborted":
        value, threshold = out.get("value"), out.get("threshold")
        detail = f" ({value:.4g} vs. limit {threshold:.4g})" if _number(value) and _number(threshold) else ""
        when = f" at t = {out['time']:.3f} s" if _number(out.get("time")) else ""
        return f"{head}\naborted by {out.get('monitor', '?')}{when}{detail}"
    if status == "failed" and out.get("message"):
        return f"{head}\nfailed: {out['message']}"
    return f"{head}\n{status}"


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _unit(log: RunLog, names: list[str]) -> tuple[str, float]:
    """The panel's unit label and the factor its data is drawn with (air gaps in mm, as the
    papers show them: metres below 0.1 m are drawn in millimetres)."""
    units = [u for u in dict.fromkeys(log.channels.get(n, {}).get("unit", "") for n in names) if u]
    if units == ["m"] and np.nanmax(np.abs(log.frame[names].to_numpy()), initial=0.0) < 0.1:
        return "mm", 1e3
    return ", ".join(units), 1.0


def plot_run(log: RunLog | str | os.PathLike[str], fig: Figure | SubFigure | None = None) -> Figure | SubFigure:
    """Draw a run (a :class:`RunLog` or the path of its MCAP) into ``fig`` (a new one if None)."""
    if not isinstance(log, RunLog):
        log = read_run(log)
    panels = _panels(log) or [("signals", [(n, "-") for n in log.signals])]
    if fig is None:
        fig = Figure(figsize=(7.5, 2.2 + 1.8 * len(panels)), layout="constrained")
    axes: list[Axes] = list(fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0])
    t = log.frame.index.to_numpy()
    out = log.outcome or {}
    t_abort = out.get("time") if out.get("status") == "aborted" and _number(out.get("time")) else None
    t_end = t[-1] if len(t) else 0.0
    planned = log.metadata.get("run", {}).get("duration")
    if t_abort is not None and _number(planned):
        t_end = max(t_end, float(planned))  # an aborted run on the axis of the run it should have been
    for ax, (title, lines) in zip(axes, panels):
        colours: dict[str, str] = {}
        unit, scale = _unit(log, [n for n, _ in lines])
        for name, style in lines:
            base = name[4:] if style == "--" else name
            colour = colours.setdefault(base, f"C{len(colours) % 10}")
            y = scale * log.frame[name].to_numpy()
            ax.plot(t, y, style, color=colour, lw=1.0 if style == "-" else 1.3, label=_label(name))
            if t_abort is not None and title == "inputs" and len(t):
                k = min(int(np.searchsorted(t, t_abort)), len(t) - 1)
                ax.plot([t[k]], [y[k]], "x", color=_ABORT, ms=8, mew=2)
        ax.set_ylabel(f"{title} [{unit}]" if unit else title)
        ax.grid(True, lw=0.4, alpha=0.6)
        ax.legend(loc="best", fontsize="small", ncols=min(4, len(lines)))
        if t_abort is not None:
            ax.axvline(t_abort, color=_ABORT, ls=":", lw=1.5)
            ax.axvspan(t_abort, max(t_end, t_abort), color="0.9", zorder=0)
    axes[-1].set_xlabel("t [s]")
    if len(t) and t_end > t[0]:
        axes[-1].set_xlim(t[0], t_end)
    fig.suptitle(_title(log), fontsize="medium")
    return fig
