"""The HTML report: one ``index.html`` with embedded PNGs, tables, the campaign and its links.

Figures, styles and the few lines of script that sort the tables are inline (no CDN: the file
opens offline); what it links to — ``metrics.csv`` / ``.parquet``, each run's log and plot, the
campaign file — is named by paths relative to the report, so the campaign directory can be moved
or archived as a whole. Only files that exist are linked.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from labrunner import safefs

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
table.sortable th{cursor:pointer;user-select:none}table.sortable th:hover{background:#e4e4e4}
.scroll{max-height:70vh;overflow:auto;border:1px solid #ddd}.scroll table{margin:0}
.scroll th{position:sticky;top:0}input.filter{width:32em;max-width:100%;margin:.4em 0;padding:.2em .4em}
"""
#: Sorts a ``table.sortable`` by the clicked column: numbers by their ``data-v``, the rest as text;
#: and filters its rows: a box above it keeps the rows where each word typed is part of some cell
#: ("aborted 0.1" keeps the aborted runs with a cell containing 0.1), and says how many are shown.
_SORT_JS = """
document.querySelectorAll("table.sortable th").forEach((th, i) => th.addEventListener("click", () => {
  const body = th.closest("table").tBodies[0], up = th.dataset.up !== "1";
  th.dataset.up = up ? "1" : "0";
  const key = r => { const c = r.cells[i], v = c.dataset.v; return v === undefined ? c.textContent : parseFloat(v); };
  [...body.rows].sort((a, b) => { const x = key(a), y = key(b);
    if (typeof x !== typeof y) return typeof x === "number" ? -1 : 1;
    return (x < y ? -1 : x > y ? 1 : 0) * (up ? 1 : -1); }).forEach(r => body.appendChild(r));
}));
document.querySelectorAll("table.sortable").forEach(table => {
  const box = document.createElement("input"), count = document.createElement("span");
  const rows = [...table.tBodies[0].rows], cells = rows.map(r => [...r.cells].map(c => c.textContent.toLowerCase()));
  box.type = "search"; box.className = "filter"; box.setAttribute("aria-label", "filter the rows");
  box.placeholder = "filter rows: words each shown row has in some cell, e.g. aborted";
  const show = () => {
    const words = box.value.toLowerCase().split(/\\s+/).filter(Boolean);
    let shown = 0;
    rows.forEach((r, j) => { r.hidden = !words.every(w => cells[j].some(c => c.includes(w))); shown += !r.hidden; });
    count.textContent = ` ${shown} of ${rows.length} rows`;
  };
  box.addEventListener("input", show);
  show();
  (table.closest(".scroll") || table).before(box, count);
});
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
    html: str = ""  # already rendered HTML, after the rest (e.g. the sortable table of all runs)


def _facts(facts: Mapping[str, object]) -> str:
    rows = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in facts.items())
    return f"<table>{rows}</table>"


def _table(title: str, frame: pd.DataFrame) -> str:
    body = frame.to_html(index=False, na_rep="–", float_format=lambda v: f"{v:.4g}", border=0, escape=True)
    return f"<h3>{html.escape(title)}</h3>{body}" if title else body


def _image(image: Image) -> str:
    data = base64.b64encode(image.png).decode("ascii")
    return (
        f'<figure><img alt="{html.escape(image.title)}" src="data:image/png;base64,{data}">'
        f"<figcaption><b>{html.escape(image.title)}.</b> {html.escape(image.caption)}</figcaption></figure>"
    )


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
    if section.html:
        parts.append(section.html)
    return "\n".join(parts)


def render_html(title: str, subtitle: str, sections: Sequence[Section]) -> str:
    """The whole report as one HTML string (UTF-8, no external resources)."""
    body = "\n".join(_section(s) for s in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n"
        f'<body><h1>{html.escape(title)}</h1><p class="sub">{html.escape(subtitle)}</p>\n{body}\n'
        f"<script>{_SORT_JS}</script></body></html>\n"
    )


def write_report(path: str | Path, title: str, subtitle: str, sections: Sequence[Section]) -> Path:
    """Write :func:`render_html` to ``path`` (atomically: temp file, then rename)."""
    path = Path(path)
    safefs.mkdir(path.parent, parents=True)
    safefs.write_atomic(path, render_html(title, subtitle, sections).encode("utf-8"), durable=False)
    return path
