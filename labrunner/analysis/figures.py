"""The figures of a campaign analysis: metric maps (or sweep plots) with overlays, and run plots.

Map layout follows the thesis: x = γ, y = k_p for the first-order MFC (Fig. 3.10); x = k_p,
y = k_d for the second-order MFC (Fig. 3.14); other pairs in grid order. Overlays are drawn only
where they are valid for every point of the map (one controller kind, one δ_t, and for k_p–k_d
one γ). Run plots: :mod:`.run_plots`.

This module loads no matplotlib: a map is computed here (grid, overlays) as a
:class:`~.drawing.FigureJob` of plain data, which :mod:`.maps` draws (:mod:`.drawing`: in the
child that draws the figures, or here).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
import pandas as pd

from labrunner.analysis.context import Context, Theories, parameter_records
from labrunner.analysis.drawing import FigureJob
from labrunner.analysis.map_data import Axis, Grid, Points, axis_label, cell_edges, is_log_spaced
from labrunner.analysis.overlays import (
    OverlayLine,
    Theory,
    dense_axis,
    gamma_kp_lines,
    kp_kd_lines,
    sweep_lines,
)
from labrunner.analysis.png import FigureStyle
from labrunner.analysis.selection import follows


def map_metrics(error: str, frame: pd.DataFrame | None = None) -> tuple[tuple[str, str, str], ...]:
    """Metric columns drawn as maps: (column, title, colour-bar text); ``error`` is "e" or "ê".

    With the table, also the largest current where the rig has currents (the valve, the plate:
    paper 1 Fig. 5, paper 2 Fig. 7) and, for several controlled outputs (the plate's y1..y3), the
    RMS of each output's error in dB re 1 µm (paper 2 reports µm and dB; columns ``*_db``, added
    by :func:`with_db_columns`).
    """
    maps = [
        ("rms_error", f"RMS of the tracking error {error}", f"RMS({error})"),
        ("input_energy", "input energy E(u) = Σ u[j]²", "E(u)"),
    ]
    if frame is None:
        return tuple(maps)
    if "max_current" in frame.columns and np.isfinite(frame["max_current"].to_numpy(dtype=float)).any():
        maps.append(("max_current", "largest current max |i|", "max |i|"))
    maps += [
        (c, f"RMS of {c.removeprefix('rms_').removesuffix('_db')} in dB re 1 µm", "dB re 1 µm")
        for c in frame.columns
        if c.endswith("_db")
    ]
    return tuple(maps)


def with_db_columns(frame: pd.DataFrame, units: Mapping[str, str]) -> pd.DataFrame:
    """The table plus ``rms_e_<y>_db`` = 20 log10(RMS(e_y) / 1 µm) for each output error in metres,
    when there are several (one map per plate sensor)."""
    cols = [
        c
        for c in frame.columns
        if c.startswith("rms_e_")
        and "@" not in c
        and not c.startswith("rms_e_hat")
        and units.get(c, units.get("rms_error")) == "m"
    ]
    if len(cols) < 2:
        return frame
    with np.errstate(divide="ignore", invalid="ignore"):
        return frame.assign(**{f"{c}_db": 20.0 * np.log10(frame[c].to_numpy(dtype=float) / 1e-6) for c in cols})


MAX_FACETS = 12  # maps per metric when a grid has more than two axes
#: Preferred (x, y) orientation of known axis pairs (thesis Figs. 3.10 and 3.14).
PAIRS = (("controller.gamma", "controller.k_p"), ("controller.k_p", "controller.k_d"))
GAINS = {"controller.gamma": "gamma", "controller.k_p": "k_p", "controller.k_d": "k_d"}
_SYMBOLS = {"gamma": "γ", "k_p": "k_p", "k_d": "k_d"}


def _with_unit(text: str, unit: str) -> str:
    return f"{text} [{unit}]" if unit else text


def choose_pair(axes: Sequence[str]) -> tuple[str, str]:
    """(x, y) keys of a map: a thesis pair if present, else the first two axes in grid order."""
    for x, y in PAIRS:
        if x in axes and y in axes:
            return x, y
    return axes[0], axes[1]


def axis_of(frame: pd.DataFrame, key: str, units: Mapping[str, str], form: str = "values") -> Axis:
    """The map axis of grid key ``key``: log scale for a ``log10`` grid axis, linear for a
    ``linspace`` one, and for listed ``values`` log if they are evenly spaced in log10."""
    values = np.sort(frame[key].dropna().unique().astype(float))
    log = form == "log10" if form in ("linspace", "log10") else is_log_spaced(values)
    return Axis(key, values, log, axis_label(key, units))


def zip_partners(campaign, key: str) -> list[str]:
    """The other grid keys zipped with ``key`` in ``campaign`` (none without one)."""
    if campaign is None:
        return []
    return [a.key for group in campaign.grid.groups if key in (b.key for b in group) for a in group if a.key != key]


def grid_forms(campaign) -> dict[str, str]:
    """Form (values | linspace | log10) of each grid axis of ``campaign`` (empty without one)."""
    if campaign is None:
        return {}
    return {axis.key: axis.form for group in campaign.grid.groups for axis in group}


def facets(frame: pd.DataFrame, extra: Sequence[str]) -> list[tuple[str, pd.DataFrame]]:
    """(title suffix, rows) per combination of the extra axes' values (at most MAX_FACETS)."""
    if not extra:
        return [("", frame)]
    values = [sorted(frame[k].dropna().unique()) for k in extra]
    out = []
    for combo in itertools.product(*values):
        mask = np.logical_and.reduce([np.isclose(frame[k].to_numpy(dtype=float), v) for k, v in zip(extra, combo)])
        if mask.any():
            out.append((", ".join(f"{k.split('.')[-1]} = {v:.4g}" for k, v in zip(extra, combo)), frame[mask]))
    return out[:MAX_FACETS]


def common_theory(rows: pd.DataFrame, theories: Theories) -> Theory | None:
    """The one theory valid for all ``rows`` (same kind, δ_t and rig constants), else None."""
    found = {}
    for row in parameter_records(rows, settings=True):
        theory = theories(row)
        if theory is None:
            return None
        found[(theory.kind, round(theory.delay, 12), tuple(sorted(theory.constants.items())))] = theory
        if len(found) > 1:
            return None
    return next(iter(found.values()), None)


def map_overlays(rows: pd.DataFrame, x, y, theories: Theories) -> tuple[list[OverlayLine], str]:
    """Overlay lines for a map of ``rows`` and a note on δ_t (or on why there are none)."""
    pair = (x.key, y.key)
    if pair not in PAIRS or theories.campaign is None:
        return [], ""
    theory = common_theory(rows, theories)
    if theory is None:
        return [], "no stability overlay: the map mixes controller kinds, differentiator delays or plants"
    note = theory.delay_note()
    if pair == ("controller.gamma", "controller.k_p") and theory.kind == "mfc1":
        return gamma_kp_lines(theory, dense_axis(cell_edges(x.values, x.log), x.log)), note
    if pair == ("controller.k_p", "controller.k_d") and theory.kind == "mfc2":
        gammas = {round(theories.gains(r).get("gamma", np.nan), 12) for r in parameter_records(rows)}
        if len(gammas) == 1:
            gamma = gammas.pop()
            return kp_kd_lines(
                theory, gamma, dense_axis(cell_edges(y.values, y.log), y.log)
            ), f"{note}, γ = {gamma:.5g}"
    return [], ""


def _outside(line: OverlayLine, x: Axis, y: Axis) -> bool:
    """Whether ``line`` misses the map's area (cell edges) entirely."""
    (x0, x1), (y0, y1) = cell_edges(x.values, x.log)[[0, -1]], cell_edges(y.values, y.log)[[0, -1]]
    if line.y is None:
        return not x0 <= float(line.x) <= x1
    if line.x is None:
        return not y0 <= float(line.y) <= y1
    xs, ys = np.asarray(line.x, dtype=float), np.asarray(line.y, dtype=float)
    return not np.any((xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1))


def mark_outside(lines: Sequence[OverlayLine], x: Axis, y: Axis) -> list[OverlayLine]:
    """The lines, those that miss the map labelled so, so that the legend does not promise a line."""
    return [replace(line, label=f"{line.label} (outside the map)") if _outside(line, x, y) else line for line in lines]


def figure_name(ctx: Context) -> str:
    """What a figure's title calls the campaign: its description (first line), else its name."""
    if ctx.campaign is None:
        return ctx.directory.name
    return (ctx.campaign.description.strip().splitlines() or [ctx.campaign.name])[0]


def _along_sweep(frame: pd.DataFrame, key: str, fixed: Mapping[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The other gains that vary along a 1-D sweep of ``key`` (a derived ``k_p = γ/4``): gain →
    (swept values, sorted; its values there); a gain equal in every row is not listed (``fixed``)."""
    out = {}
    for column, gain in GAINS.items():
        if column == key or gain not in fixed or column not in frame.columns:
            continue
        pairs = frame[[key, column]].apply(pd.to_numeric, errors="coerce").dropna().groupby(key)[column].mean()
        if pairs.nunique() > 1:
            out[gain] = (pairs.index.to_numpy(float), pairs.to_numpy(float))
    return out


def _interpolated(along: Mapping[str, tuple[np.ndarray, np.ndarray]], log: bool):
    """The gains of ``along`` at a swept value, interpolated between the runs (in log10 on a log axis)."""
    if not along:
        return None
    scale = np.log10 if log else np.asarray
    return lambda v: {g: float(np.interp(scale(v), scale(xs), ys)) for g, (xs, ys) in along.items()}


def _gain_text(gain: str, value: float, along: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> str:
    """``k_p = 50`` for a fixed gain; its range for one that varies along the sweep."""
    if gain not in along:
        return f"{_SYMBOLS[gain]} = {value:.5g}"
    values = along[gain][1]
    return f"{_SYMBOLS[gain]} = {values.min():.4g} … {values.max():.4g} along the sweep"


def map_jobs(
    frame: pd.DataFrame, ctx: Context, theories: Theories, style: FigureStyle | None = None
) -> list[FigureJob]:
    """The RMS and energy maps (2-D grids) or the sweep plot (1-D) as figures to draw, their
    overlays computed now (the theory, once), the drawing left to :mod:`.drawing` (so that a
    forked process can draw them); ``style``: their size, formats and whether titled."""
    jobs: list[FigureJob] = []
    style = style or FigureStyle()
    name = figure_name(ctx)
    units, forms = ctx.units, grid_forms(ctx.campaign)
    if len(ctx.axes) == 1:
        key = ctx.axes[0]
        x = axis_of(frame, key, units, forms.get(key, "values"))
        lines: list[OverlayLine] = []
        note = ""
        scattered = [k for k in zip_partners(ctx.campaign, key) if not follows(frame, key, k)]
        theory = common_theory(frame, theories) if key in GAINS and theories.campaign is not None else None
        if scattered:  # no line through the runs, no bound (it would need a gain the sweep does not fix)
            note = "\n" + ", ".join(
                f"{axis_label(k, units)} scattered over the sweep: runs unjoined, no bound" for k in scattered
            )
        elif theory is not None:
            fixed = theories.gains(frame.iloc[0])
            along = _along_sweep(frame, key, fixed)
            dense = dense_axis(x.values, x.log, 400)
            lines = [
                line  # only what the plot shows (ρ beyond the swept range would stretch the axis or list an unseen line)
                for line in sweep_lines(theory, GAINS[key], dense, fixed, _interpolated(along, x.log))
                if dense[0] <= float(line.x) <= dense[-1]  # type: ignore[arg-type]
            ]
            others = ", ".join(_gain_text(k, v, along) for k, v in fixed.items() if k != GAINS[key])
            note = f"\n{theory.delay_note()}" + (f", {others}" if others else "")
        columns = [(c, _with_unit(label, units.get(c, ""))) for c, _, label in map_metrics(ctx.error)]
        title = f"{name}: RMS of {ctx.error} and input energy over {x.label}{note}"
        names = [c for c, _ in columns]
        points = Points.of(frame, [key, *names, *(f"{c}_until_abort" for c in names)])
        return [
            FigureJob(
                ctx.out / "sweep.png",
                f"RMS of {ctx.error} and input energy over {x.label}",
                "sweep_figure",
                (points, x, columns),
                {"title": title if style.title else "", "overlays": lines, "joined": not scattered},
                style,
            )
        ]
    if len(ctx.axes) < 2:
        return jobs
    kx, ky = choose_pair(ctx.axes)
    extra = [k for k in ctx.axes if k not in (kx, ky)]
    for i, (suffix, rows) in enumerate(facets(frame, extra)):
        x, y = axis_of(rows, kx, units, forms.get(kx, "values")), axis_of(rows, ky, units, forms.get(ky, "values"))
        lines, note = map_overlays(rows, x, y, theories)
        lines = mark_outside(lines, x, y)
        rows = with_db_columns(rows, units)
        metrics = map_metrics(ctx.error, rows)
        grid = Grid.of(rows, x, y, [column for column, _, _ in metrics])  # one copy for the facet's maps
        for column, title, label in metrics:
            head = f"{name}: {title}"
            sub = ", ".join(s for s in (suffix, note) if s)
            kwargs = {
                "title": "" if not style.title else f"{head}\n{sub}" if sub else head,
                "colour_label": _with_unit(label, units.get(column, "")),
                "overlays": lines,
            }
            tag = f"_{i + 1}" if extra else ""
            caption = f"{title} over {x.label} and {y.label}" + (f" ({suffix})" if suffix else "")
            path = ctx.out / f"map_{column}{tag}.png"
            jobs.append(FigureJob(path, caption, "map_figure", (grid, column), kwargs, style))
    return jobs
