"""A self-contained HTML report: one ``index.html`` with embedded PNGs, tables and the campaign.

Everything is inline (CSS, images as base64 data URIs), so the file opens offline, can be mailed
and archived alone, and never points at files that may move.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1100px;
color:#222;line-height:1.45;padding:0 1em}
h1{margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
.sub{color:#555;margin-top:0}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}th{background:#f2f2f2}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{color:#444;font-size:.9em}
pre{background:#f7f7f7;border:1px solid #ddd;padding:.8em;overflow-x:auto;font-size:.85em}
.grid{display:grid;grid-template-columns:repeat(auto-fit,minmax(480px,1fr));gap:1em}
.warn{background:#fff4e5;border-left:4px solid #f0a030;padding:.5em 1em}
"""


@dataclass(frozen=True)
class Image:
    """One PNG for the report, with a title and a caption."""

    title: str
    png: bytes
    caption: str = ""


@dataclass(frozen=True)
class Section:
    """A titled part of the report: paragraphs, key/value facts, tables, images, preformatted text."""

    title: str
    paragraphs: Sequence[str] = ()
    facts: Mapping[str, object] = field(default_factory=dict)
    tables: Sequence[tuple[str, pd.DataFrame]] = ()
    images: Sequence[Image] = ()
    pre: str = ""
    warning: bool = False


def _facts(facts: Mapping[str, object]) -> str:
    rows = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in facts.items())
    return f"<table>{rows}</table>"


def _table(title: str, frame: pd.DataFrame) -> str:
    body = frame.to_html(index=False, na_rep="–", float_format=lambda v: f"{v:.4g}", border=0, escape=True)
    return f"<h3>{html.escape(title)}</h3>{body}" if title else body


def _image(image: Image) -> str:
    data = base64.b64encode(image.png).decode("ascii")
    return (f'<figure><img alt="{html.escape(image.title)}" src="data:image/png;base64,{data}">'
            f"<figcaption><b>{html.escape(image.title)}.</b> {html.escape(image.caption)}</figcaption></figure>")


def _section(section: Section) -> str:
    parts = [f"<h2>{html.escape(section.title)}</h2>"]
    cls = ' class="warn"' if section.warning else ""
    parts += [f"<p{cls}>{html.escape(p)}</p>" for p in section.paragraphs]
    if section.facts:
        parts.append(_facts(section.facts))
    parts += [_table(title, frame) for title, frame in section.tables]
    if section.images:
        parts.append('<div class="grid">' + "".join(_image(i) for i in section.images) + "</div>")
    if section.pre:
        parts.append(f"<pre>{html.escape(section.pre)}</pre>")
    return "\n".join(parts)


def render_html(title: str, subtitle: str, sections: Sequence[Section]) -> str:
    """The whole report as one HTML string (UTF-8, no external resources)."""
    body = "\n".join(_section(s) for s in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n"
        f"<body><h1>{html.escape(title)}</h1><p class=\"sub\">{html.escape(subtitle)}</p>\n{body}\n</body></html>\n"
    )


def write_report(path: str | Path, title: str, subtitle: str, sections: Sequence[Section]) -> Path:
    """Write :func:`render_html` to ``path`` (atomically: temp file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(render_html(title, subtitle, sections), encoding="utf-8")
    tmp.replace(path)
    return path


# -- the campaign report ---------------------------------------------------------------------
_SHOWN = 10  # rows of the best/aborted tables


def _png(path: Path) -> bytes:
    return Path(path).read_bytes()


def _param_columns(frame: pd.DataFrame, axes: Sequence[str]) -> list[str]:
    return [c for c in axes if c in frame.columns] or [c for c in frame.columns if "." in c]


def _campaign_section(ctx, frame: pd.DataFrame) -> Section:
    campaign = ctx.campaign
    if campaign is None:
        return Section("Campaign", paragraphs=[f"Directory {ctx.directory}. {ctx.note}."], warning=True)
    facts: dict[str, object] = {
        "name": campaign.name, "rig": f"{campaign.rig} ({campaign.rig_info.description or campaign.rig_info.kind})",
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
    return Section("Campaign", paragraphs=[campaign.description] if campaign.description else [], facts=facts,
                   pre=campaign.source)


def _section_text(campaign, section: str) -> str:
    """``k = v`` of a base section, leaving out keys the grid or [derived] sets per point."""
    varied = set(campaign.grid.keys) | {key for key, _ in campaign.derived}
    items = [f"{k} = {v}" for k, v in campaign.base.get(section, {}).items() if f"{section}.{k}" not in varied]
    return ", ".join(items) or "–"


def _outcome_section(summary: Mapping[str, object]) -> Section:
    keys = ("points", "runs", "completed", "no_motion", "oscillating", "aborted", "failed", "planned", "claimed")
    facts = {k.replace("_", "-"): summary[k] for k in keys if k in summary}
    agree = summary.get("agreement") or {}
    paragraphs = []
    if agree.get("share") is not None:
        paragraphs.append(
            f"Theory vs. runs ({agree['case']}): {agree['share']:.1%} of {agree['n_compared']} points agree "
            f"(completed or no motion ⇔ predicted stable, aborted or oscillating ⇔ predicted unstable); "
            f"{agree['n_excluded']} points within ±{agree['margin']:.0%} of a predicted bound are left out; "
            f"{agree['false_stable']} aborted although predicted stable, {agree['false_unstable']} completed "
            "although predicted unstable.")
    else:
        paragraphs.append("No stability case applies to this campaign (or no run finished), so no agreement is given.")
    return Section("Outcomes", paragraphs=paragraphs, facts=facts)


def _run_table(frame: pd.DataFrame, columns: Sequence[str]) -> pd.DataFrame:
    """The given columns that hold any value, named by their last dotted part."""
    shown = [c for c in columns if c in frame.columns and frame[c].notna().any()]
    return frame[shown].rename(columns=lambda c: c.split(".")[-1] if "." in c else c)


def campaign_report(frame: pd.DataFrame, ctx, summary: Mapping[str, object], maps: Sequence[tuple[Path, str]],
                    chosen: Mapping[str, pd.Series], runs: Mapping[str, Path]) -> Path:
    """Compose and write ``index.html`` of a campaign analysis into ``ctx.out``.

    ``ctx`` is the analysis context (campaign, directory, axes, units); ``maps`` (PNG, title)
    pairs; ``chosen`` the table rows of the plotted runs, ``runs`` their PNGs, both keyed by label
    ("best", ...).
    """
    params = _param_columns(frame, ctx.axes)
    metrics = ["rms_error", "input_energy", "max_abs_input", "max_current"]
    sections = [_campaign_section(ctx, frame), _outcome_section(summary)]
    if maps:
        sections.append(Section("Maps", paragraphs=[
            "Markers: red triangle = aborted by the safety routine, white circle = no motion (input too small to "
            "move the load), black cross = completed, grey square = failed, orange diamond = completed but oscillating or "
            "pinned at an input limit (detector). Grey cells: no metric for the whole run. "
            "Lines: stability bounds of the theory for the loop delay: the differentiator's δ_t plus the rig's sensor delay, if any."],
            images=[Image(title, _png(path)) for path, title in maps]))
    if runs:
        images = [Image(f"{label} run", _png(path), _run_caption(chosen[label], params, ctx.error))
                  for label, path in runs.items()]
        sections.append(Section("Selected runs", images=images))
    done = frame[frame["status"] == "completed"].sort_values("rms_error")
    tables = []
    if not done.empty:
        tables.append((f"Best {min(_SHOWN, len(done))} completed runs by RMS of {ctx.error}",
                       _run_table(done.head(_SHOWN), ["seq", "id", *params, *metrics])))
    aborted = frame[frame["status"] == "aborted"].sort_values("seq")
    if not aborted.empty:
        tables.append((f"First {min(_SHOWN, len(aborted))} of {len(aborted)} aborted runs",
                       _run_table(aborted.head(_SHOWN), ["seq", "id", *params, "monitor", "abort_time", "abort_value"])))
    failed = frame[frame["status"] == "failed"]
    if not failed.empty:
        tables.append((f"{len(failed)} failed runs", _run_table(failed.head(_SHOWN), ["seq", "id", *params, "monitor"])))
    if tables:
        sections.append(Section("Runs", tables=tables))
    problems = summary.get("problems") or []
    if problems:
        sections.append(Section("Damaged and quarantined files", warning=True, paragraphs=[
            f"{len(problems)} file(s) could not be used as they are; metrics of unreadable logs fall back to the "
            "ledger's summary."], tables=[("", pd.DataFrame(problems, columns=["kind", "path", "detail"]))]))
    sections.append(Section("Files", paragraphs=[
        "metrics.csv and metrics.parquet (next to this file) hold one row per grid point: parameters, ledger "
        "state, outcome, and the metrics of its run log."]))
    name = ctx.campaign.name if ctx.campaign is not None else ctx.directory.name
    subtitle = f"labrunner analysis of {ctx.directory} — {summary['runs']} runs of {summary['points']} points"
    return write_report(ctx.out / "index.html", f"Campaign {name}", subtitle, sections)


def _value(v: object) -> str:
    """A grid value for a caption: numbers to 4 digits, anything else (an input law's name) as is."""
    return f"{float(v):.4g}" if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def _run_caption(row: pd.Series, params: Sequence[str], error: str) -> str:
    """Point, parameters, outcome and metrics of a plotted run."""
    values = ", ".join(f"{k.split('.')[-1]} = {_value(row[k])}" for k in params if pd.notna(row.get(k)))
    text = f"Point {row['seq']} ({row['id']}): {values}; {row['status']}"
    if row["status"] == "aborted" and pd.notna(row.get("abort_time")):
        text += f" by {row.get('monitor')} at t = {float(row['abort_time']):.3f} s"
    return f"{text}; RMS({error}) = {float(row['rms_error']):.4g}, E(u) = {float(row['input_energy']):.4g}."
