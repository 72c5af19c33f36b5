"""The campaign's ``index.html``: campaign file, outcomes, the theory's bounds, maps, chosen runs,
every run in one sortable table with links to its log and plot, and the files behind it all.

Outcomes are counted with :func:`labrunner.campaign.progress.format_counts`, in the words
``run``, ``status`` and ``analyse`` print. Links are relative to the report and made only to
files that exist; a run without a plot names the command that makes one.
"""

from __future__ import annotations

import html
import math
import os
import posixpath
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner.analysis.context import parameter_records
from labrunner.analysis.figures import common_theory
from labrunner.analysis.overlays import EQUATIONS
from labrunner.analysis.report import Image, Section, write_report
from labrunner.analysis.table import FOREIGN
from labrunner.campaign.progress import format_counts
from labrunner.campaign.rig_timing import timing_line
from labrunner.metrics import CUT_SHORT, UNTIL_ABORT
from labrunner.rigs.device import lawflag

#: Metric columns of the table of all runs (the ones ranked by, then those of aborted runs).
METRICS = ("rms_error", "rms_error_hat", "input_energy", "max_abs_input", "max_current")
_GAMMAS_SHOWN = 5  # γ values at which the report states the bounds


def _link(out: Path, target: Path, text: str) -> str:
    """``<a>`` to ``target`` relative to the report folder, or the bare text if it does not exist."""
    if not target.is_file():
        return html.escape(text)
    rel = os.path.relpath(target.resolve(), out.resolve())
    return f'<a href="{html.escape(Path(rel).as_posix())}">{html.escape(text)}</a>'


def _param_columns(frame: pd.DataFrame, axes: Sequence[str]) -> list[str]:
    return [c for c in axes if c in frame.columns] or [c for c in frame.columns if "." in c]


def _campaign_section(ctx) -> Section:
    campaign = ctx.campaign
    copy = _link(ctx.out, ctx.directory / "campaign.toml", "campaign.toml")
    if campaign is None:
        return Section("Campaign", paragraphs=[f"Directory {ctx.directory}. {ctx.note}."], warning=True)
    facts: dict[str, object] = {
        "name": campaign.name,
        "rig": f"{campaign.rig} ({campaign.rig_info.description or campaign.rig_info.kind})",
        "sampling frequency f_s": f"{campaign.fs:g} Hz",
        "duration": f"{campaign.duration:g} s" if campaign.duration else "the reference's length",
        "controller": _section_text(campaign, "controller"),
        "differentiator": _section_text(campaign, "differentiator"),
        "points": campaign.size,
    }
    for group in campaign.grid.groups:
        for axis in group:
            values = [v for v in axis.values if isinstance(v, (int, float))]
            span = f"{min(values):.4g} … {max(values):.4g}" if values else ", ".join(map(str, axis.values))
            facts[f"grid: {axis.key}"] = f"{len(axis.values)} values, {span}"
    for key, expr in campaign.derived:
        facts[f"derived: {key}"] = expr.source
    constants = ", ".join(f"{k} = {v:g}" for k, v in campaign.rig_info.constants.items())
    if constants:
        facts["rig constants (nominal)"] = constants
    if campaign.logging.get("samples_hz"):
        facts["logging"] = (
            f"/run/samples thinned to ≈ {campaign.logging['samples_hz']:g} Hz ([logging] samples_hz); "
            "/run/blocks keep every sample"
        )
    paragraphs = [campaign.description] if campaign.description else []
    return Section(
        "Campaign",
        paragraphs=paragraphs,
        facts=facts,
        pre=campaign.source,
        html=f"<p>The campaign file above is kept as {copy} in the campaign directory.</p>"
        if copy.startswith("<a")
        else "",
    )


def _section_text(campaign, section: str) -> str:
    """``k = v`` of a base section, leaving out keys the grid or [derived] sets per point."""
    varied = set(campaign.grid.keys) | {key for key, _ in campaign.derived}
    items = [f"{k} = {v}" for k, v in campaign.base.get(section, {}).items() if f"{section}.{k}" not in varied]
    return ", ".join(items) or "–"


def _outcome_section(summary: Mapping[str, Any]) -> Section:
    agree = summary.get("agreement") or {}
    paragraphs = [f"{summary['runs']} runs of {summary['points']} points: {format_counts(summary['outcomes'])}."]
    if agree.get("share") is not None:
        paragraphs.append(
            f"Theory vs. runs ({agree['case']}): {agree['share']:.1%} of {agree['n_compared']} points agree "
            f"(completed or no-motion ⇔ predicted stable, aborted or oscillating ⇔ predicted unstable); "
            f"{agree['n_excluded']} points within ±{agree['margin']:.0%} of a predicted bound are left out; "
            f"{agree['false_stable']} aborted although predicted stable, {agree['false_unstable']} completed "
            "although predicted unstable."
        )
    else:
        paragraphs.append("No stability case applies to this campaign (or no run finished), so no agreement is given.")
    law = summary.get("law_check")
    if law:
        paragraphs.append(
            lawflag.line(law) + ". Each device-loop run's logged inputs, references and estimates were recomputed "
            "from its logged measurements by the reference law (docs/control-laws.md); a diverged run's "
            "outcome is the firmware's, not the law's."
        )
    facts: dict[str, object] = dict(summary["outcomes"])
    if summary.get("oscillating"):
        facts["of the completed: oscillating (detector)"] = summary["oscillating"]
    if "timing" in summary:
        paragraphs.append(timing_line(summary["timing"]).capitalize() + " — per run in metrics.csv.")
    return Section("Outcomes", paragraphs=paragraphs, facts=facts)


def _interval(bounds: Mapping[str, Any] | None, key: str) -> str:
    if bounds is None:
        return "no theory here (outside its domain)"
    value = bounds.get(key)
    if value is None:
        return "none stable"
    if isinstance(value[0], (list, tuple)):
        return " or ".join(f"({lo:.5g}, {hi:.5g})" for lo, hi in value)
    return f"({value[0]:.5g}, {value[1]:.5g})"


def _theory_section(frame: pd.DataFrame, theories) -> Section | None:
    """The stability bounds (thesis section 2.4, corrected appendix A) the maps and the agreement use."""
    if theories.campaign is None or frame.empty:
        return None
    theory = common_theory(frame, theories)
    if theory is None or not theory.cases():
        return None
    gains = [theories.gains(r) for r in parameter_records(frame.iloc[:: max(1, len(frame) // 200)])]
    gammas = sorted({g["gamma"] for g in gains if "gamma" in g})
    if len(gammas) > _GAMMAS_SHOWN:
        gammas = [gammas[round(i * (len(gammas) - 1) / (_GAMMAS_SHOWN - 1))] for i in range(_GAMMAS_SHOWN)]
    k_ds = sorted({g["k_d"] for g in gains if "k_d" in g})
    k_d = k_ds[len(k_ds) // 2] if k_ds else None
    rows = []
    for case in theory.cases():
        for gamma in gammas:
            b = theory.bounds(case, gamma, k_d if case.startswith("mfc2") else None)
            row = {
                "case": case,
                "thesis equations": EQUATIONS[case],
                "γ": f"{gamma:.5g}",
                "k_p interval": _interval(b, "k_p"),
            }
            if case.startswith("mfc2"):
                row.update({"k_d interval": _interval(b, "k_d"), "k_p at k_d": f"{k_d:.5g}"})
            rows.append(row)
    constants = ", ".join(f"{k} = {v:g}" for k, v in theory.constants.items() if isinstance(v, (int, float)))
    return Section(
        "Stability bounds used",
        paragraphs=[
            f"Controller {theory.kind}; loop delay {theory.delay_note()}; rig constants {constants}. Open intervals of the "
            "gains for which the closed loop is predicted stable (thesis section 2.4 and appendix A, corrected), at γ values "
            "of the grid; these are the lines on the maps and the prediction the agreement counts."
        ],
        tables=[("", pd.DataFrame(rows))],
    )


def _cell(value: Any) -> str:
    """One table cell: numbers carry ``data-v`` for sorting; NaN and None are a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)) or value is pd.NA:
        return "<td>–</td>"
    if isinstance(value, (bool, np.bool_)):
        return f"<td>{'yes' if value else 'no'}</td>"
    if isinstance(value, (int, np.integer)):
        return f'<td data-v="{int(value)}">{int(value)}</td>'
    if isinstance(value, (float, np.floating)):
        return f'<td data-v="{float(value)!r}">{float(value):.4g}</td>'
    return f"<td>{html.escape(str(value))}</td>"


def _column_cells(values: pd.Series) -> list[str]:
    """:func:`_cell` of every value of a column, the type looked at once per column (a table of
    10 000 runs has 160 000 cells): floats and nullable integers formatted directly."""
    if pd.api.types.is_float_dtype(values.dtype):
        return [
            "<td>–</td>" if v != v else f'<td data-v="{v!r}">{v:.4g}</td>'
            for v in values.to_numpy(dtype=float).tolist()
        ]
    if pd.api.types.is_integer_dtype(values.dtype):
        missing = values.isna().to_numpy().tolist()
        ints = values.fillna(0).astype("int64").tolist()
        return ["<td>–</td>" if m else f'<td data-v="{v}">{v}</td>' for v, m in zip(ints, missing)]
    return [_cell(v) for v in values.tolist()]


def _link_cells(out: Path, directory: Path, logs: Sequence[Any], states: Sequence[Any]) -> list[str]:
    """:func:`_link` of each run's log (``"log"``; a dash for a point without one; no link to a
    log that is another point's run), the campaign directory resolved once instead of once per run."""
    base = Path(os.path.relpath(directory.resolve(), out.resolve())).as_posix()
    cells = []
    for log, state in zip(logs, states, strict=True):
        if not isinstance(log, str):
            cells.append("<td>–</td>")
        elif state == FOREIGN:
            cells.append(f"<td>{FOREIGN} log</td>")
        elif (directory / log).is_file():
            cells.append(f'<td><a href="{html.escape(posixpath.normpath(posixpath.join(base, log)))}">log</a></td>')
        else:
            cells.append("<td>log</td>")
    return cells


#: Rows of the report's runs table at most: a campaign of 10^5 or 10^6 points would make a page
#: of hundreds of MB that no browser sorts; the tables in metrics.csv / .parquet hold every point.
TABLE_ROWS = 10_000


def _table_rows(frame: pd.DataFrame) -> pd.DataFrame:
    """:data:`TABLE_ROWS` rows of a larger table: the best half by rms_error, then aborted and failed
    runs and the other points in grid order (positions found from two columns: no copy of the
    table but the rows shown)."""
    taken = np.zeros(len(frame), dtype=bool)
    best = np.zeros(0, dtype=np.intp)
    if "rms_error" in frame.columns:
        best = frame.index.get_indexer(frame["rms_error"].nsmallest(TABLE_ROWS // 2).index)
    taken[best] = True
    trouble = np.flatnonzero(frame["outcome"].isin(["aborted", "failed"]).to_numpy(dtype=bool) & ~taken)
    trouble = trouble[: TABLE_ROWS // 4]
    taken[trouble] = True
    others = np.flatnonzero(~taken)[: TABLE_ROWS - len(best) - len(trouble)]
    return frame.iloc[np.concatenate([best, trouble, others])]


def runs_table(frame: pd.DataFrame, ctx, params: Sequence[str], plots: Mapping[str, Path]) -> str:
    """Every point in one sortable table: outcome, parameters, metrics, abort, log and plot links."""
    metrics = [c for c in METRICS if c in frame.columns and frame[c].notna().any()]
    until = [
        c + UNTIL_ABORT for c in metrics if c + UNTIL_ABORT in frame.columns and frame[c + UNTIL_ABORT].notna().any()
    ]
    abort = [c for c in ("monitor", "abort_time") if c in frame.columns and frame[c].notna().any()]
    abort += [
        c for c in ("law_check", "law_arithmetic") if c in frame.columns and frame[c].fillna("").astype(bool).any()
    ]
    columns = ["seq", "id", "outcome", *params, *metrics, *until, *abort, "n_samples"]
    columns = [c for c in columns if c in frame.columns]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)  # the names of metrics.csv and the API
    cells = [_column_cells(frame[c]) for c in columns]
    states = frame["log_state"].tolist() if "log_state" in frame.columns else [None] * len(frame)
    cells.append(_link_cells(ctx.out, ctx.directory, frame["log_path"].tolist(), states))
    cells.append(
        [f"<td>{_link(ctx.out, plots[i], 'plot')}</td>" if i in plots else "<td>–</td>" for i in frame["id"].tolist()]
    )
    rows = "".join(f"<tr>{''.join(row)}</tr>" for row in zip(*cells))
    return (
        f'<div class="scroll"><table class="sortable"><thead><tr>{head}<th>log</th><th>plot</th></tr></thead>'
        f"<tbody>{rows}</tbody></table></div>"
    )


def campaign_report(
    frame: pd.DataFrame,
    ctx,
    summary: Mapping[str, Any],
    maps: Sequence[tuple[Path, str]],
    chosen: Mapping[str, pd.Series],
    plots: Mapping[str, Path],
    theories,
    extra: Sequence[Section] = (),
) -> Path:
    """Compose and write ``index.html`` of a campaign analysis into ``ctx.out``.

    ``ctx`` is the analysis context (campaign, directory, axes, units); ``maps`` (PNG, title)
    pairs; ``chosen`` the table rows of the selected runs by label ("best", ...); ``plots`` the run
    plots made, by point id; ``theories`` the analysis's :class:`~labrunner.analysis.analyse.Theories`;
    ``extra`` sections follow the outcomes (a guided campaign's walk).
    """
    params = _param_columns(frame, ctx.axes)
    sections = [_campaign_section(ctx), _outcome_section(summary), *extra]
    theory = _theory_section(frame, theories)
    if theory is not None:
        sections.append(theory)
    if maps:
        sections.append(
            Section(
                "Maps",
                paragraphs=[
                    "Markers: red triangle = aborted by the safety routine, white circle = no-motion (input too small to "
                    "move the load), black cross = completed, grey square = failed, orange diamond = completed but oscillating or "
                    "pinned at an input limit (detector). A map too dense for a marker a cell shows the outcomes as flat "
                    "cell colours instead, named in its legend. Grey cells: no metric for the whole run. "
                    "Lines: stability bounds of the theory for the loop delay: the differentiator's δ_t plus the rig's sensor delay, if any."
                ],
                images=[Image(title, path.read_bytes()) for path, title in maps],
            )
        )
    images, links = [], []
    for label, row in chosen.items():
        plot = plots.get(row["id"])
        if plot is not None:
            images.append(Image(f"{label} run", plot.read_bytes(), _run_caption(row, params, ctx.error)))
            log = (
                f"{FOREIGN} log"
                if row.get("log_state") == FOREIGN
                else _link(ctx.out, ctx.directory / row["log_path"], "log")
            )
            links.append(
                f"{html.escape(label)}: point {html.escape(str(row['id']))} ({log}, {_link(ctx.out, plot, 'plot')})"
            )
    if images:
        sections.append(Section("Selected runs", images=images, html="<p>" + "; ".join(links) + ".</p>"))
    shown = frame if len(frame) <= TABLE_ROWS else _table_rows(frame)
    which = (
        f"All {len(frame)} points"
        if shown is frame
        else f"{len(shown)} of the {len(frame)} points (the best {TABLE_ROWS // 2} by rms_error, then the first "
        "aborted and failed ones and the rest in grid order; every point is in metrics.csv / metrics.parquet, "
        "below)"
    )
    sections.append(
        Section(
            "All runs" if shown is frame else "Runs",
            paragraphs=[
                f"{which}; click a column's name to sort by it. rms_error, input_energy, … describe whole runs; "
                f"an aborted (or failed) run's metrics cover the run up to its abort (or failure) and are in the columns "
                f"ending in {UNTIL_ABORT}. "
                f"Plot any run with `labrunner analyse {ctx.directory} --plot ID` (or --plot aborted, --plot all), which "
                f"adds it here, or with `labrunner plot {ctx.directory}/runs/ID.mcap`."
            ],
            html=runs_table(shown, ctx, params, plots),
        )
    )
    problems = summary.get("problems") or []
    if problems:
        sections.append(
            Section(
                "Damaged and quarantined files",
                warning=True,
                paragraphs=[
                    f"{len(problems)} file(s) could not be used as they are; metrics of unreadable logs fall back to the "
                    "ledger's."
                ],
                tables=[("", pd.DataFrame(problems, columns=["kind", "path", "detail"]))],
            )
        )
    files = [
        _link(ctx.out, ctx.out / "metrics.csv", "metrics.csv"),
        _link(ctx.out, ctx.out / "metrics.parquet", "metrics.parquet"),
    ]
    sections.append(
        Section(
            "Files",
            html=(
                f"<p>{files[0]} and {files[1]} hold one row per grid point: parameters, outcome, every metric of its run "
                "(aborted and failed runs' in the _until_abort columns) and the path of its log relative to the table; the logs "
                f"are MCAP files (Foxglove plots /run/samples.&lt;signal&gt;__&lt;unit&gt;). Campaign file: "
                f"{_link(ctx.out, ctx.directory / 'campaign.toml', 'campaign.toml')}; ledger: "
                f"{_link(ctx.out, ctx.directory / 'ledger.sqlite', 'ledger.sqlite')}.</p>"
            ),
        )
    )
    name = ctx.campaign.name if ctx.campaign is not None else ctx.directory.name
    subtitle = f"labrunner analysis of {ctx.directory} — {summary['runs']} runs of {summary['points']} points"
    return write_report(ctx.out / "index.html", f"Campaign {name}", subtitle, sections)


def _value(v: object) -> str:
    """A grid value for a caption: numbers to 4 digits, anything else (an input law's name) as is."""
    return f"{float(v):.4g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def _run_caption(row: pd.Series, params: Sequence[str], error: str) -> str:
    """Point, parameters, outcome and metrics of a plotted run."""
    values = ", ".join(f"{k.split('.')[-1]} = {_value(row[k])}" for k in params if pd.notna(row.get(k)))
    text = f"Point {row['seq']} ({row['id']}): {values}; {row['outcome']}"
    suffix = UNTIL_ABORT if row["outcome"] in CUT_SHORT else ""
    if row["outcome"] == "aborted" and pd.notna(row.get("abort_time")):
        text += f" by {row.get('monitor')} at t = {float(row['abort_time']):.3f} s"
    rms, energy = row.get("rms_error" + suffix), row.get("input_energy" + suffix)
    scope = f" up to the {'abort' if row['outcome'] == 'aborted' else 'failure'}" if suffix else ""
    if rms is None or pd.isna(rms):
        return f"{text}."
    return f"{text}; RMS({error}) = {float(rms):.4g}, E(u) = {float(energy):.4g}{scope}."
