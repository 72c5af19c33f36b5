"""Several runs in one figure, like the thesis's Figs. 3.12, 3.18 and 3.22 and paper 1's Fig. 8.

One panel per controlled output (each run in its own colour, the first run's reference dashed in
black) and one per input, over a shared time axis. Runs are labelled by what differs between them:
the grid values their logs record (e.g. ``gamma = 421.7, k_p = 237.1``), else the file name; an
aborted run ends in a cross at its abort time. Used by ``labrunner plot A.mcap B.mcap …``. No pyplot.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from labrunner.errors import InvalidParameter
from labrunner.logs import RunLog, read_run
from labrunner.runplot import common_unit, is_number, signal_label, signal_roles

MAX_RUNS = 20  # beyond this the colours repeat and the legend hides the data


def _labels(logs: Sequence[RunLog], names: Sequence[str]) -> list[str]:
    """Per run, the grid values in which the runs differ (all of them if none differ), else its file."""
    params = [dict(log.metadata.get("parameters") or {}) for log in logs]
    keys = list(dict.fromkeys(k for p in params for k in p))
    differ = [k for k in keys if len({repr(p.get(k)) for p in params}) > 1] or keys
    out = []
    for p, name in zip(params, names):
        shown = ", ".join(
            f"{k.rsplit('.', 1)[-1]} = {p[k]:.4g}" if is_number(p.get(k)) else f"{k.rsplit('.', 1)[-1]} = {p.get(k)}"
            for k in differ
            if k in p
        )
        out.append(shown or name)
    return out


def plot_overlay(paths: Sequence[str | os.PathLike[str]]) -> Figure:
    """Overlay the runs of ``paths`` (MCAP files of one rig): outputs with references, then inputs."""
    if not 2 <= len(paths) <= MAX_RUNS:
        raise InvalidParameter("RUN.mcap", f"an overlay takes 2 to {MAX_RUNS} run logs, got {len(paths)}")
    logs = [read_run(p) for p in paths]
    roles = [signal_roles(log) for log in logs]
    names = set(logs[0].signals)
    outputs = [r[4:] for r in roles[0].get("reference", []) if r[4:] in names] or roles[0].get(
        "controlled", roles[0].get("output", [])
    )
    inputs = roles[0].get("input", [])
    for path, r in zip(paths, roles[1:]):
        if r.get("input", []) != inputs:
            raise InvalidParameter("RUN.mcap", f"{str(path)!r} has other inputs than {str(paths[0])!r}: not one rig")
    panels = [(n, "outputs") for n in outputs] + [(n, "inputs") for n in inputs]
    labels = _labels(logs, [Path(p).stem for p in paths])
    fig = Figure(figsize=(7.5, 2.0 + 1.9 * len(panels)), layout="constrained")
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (name, kind) in zip(axes, panels):
        unit, scale = common_unit(logs[0], [name])
        ref = f"ref_{name}"
        if kind == "outputs" and ref in logs[0].signals:
            ax.plot(
                logs[0].frame.index,
                scale * logs[0].frame[ref].to_numpy(),
                "--",
                color="black",
                lw=1.3,
                label=f"{signal_label(ref)} ({labels[0]})",
            )
        for i, (log, label) in enumerate(zip(logs, labels)):
            if name not in log.signals:
                continue
            t, y = log.frame.index.to_numpy(), scale * log.frame[name].to_numpy()
            ax.plot(t, y, color=f"C{i % 10}", lw=1.0, label=label if ax is axes[0] else None)
            out = log.outcome or {}
            if out.get("status") == "aborted" and len(t):
                ax.plot([t[-1]], [y[-1]], "x", color=f"C{i % 10}", ms=8, mew=2)
        ax.set_ylabel(f"{signal_label(name)} [{unit}]" if unit else signal_label(name))
        ax.grid(True, lw=0.4, alpha=0.6)
    axes[0].legend(loc="best", fontsize="small", ncols=2)
    axes[-1].set_xlabel("t [s]")
    ends = [log.frame.index[-1] for log in logs if log.n_samples]
    if ends:
        axes[-1].set_xlim(0.0, float(np.max(ends)))
    fig.suptitle(f"{len(logs)} runs overlaid", fontsize="medium")
    return fig
