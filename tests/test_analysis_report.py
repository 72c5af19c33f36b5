"""The HTML report is one self-contained file: embedded images, tables, escaped text."""

import base64
import re
from types import SimpleNamespace

import pandas as pd
import pytest

from labrunner.analysis.campaign_report import _cell, _link, runs_table
from labrunner.analysis.report import Image, Section, write_report

PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNk+M9QDwADhgGAWjR9awAAAABJRU5ErkJggg=="
)


def test_report_is_self_contained(tmp_path):
    sections = [
        Section(
            "Campaign",
            paragraphs=["γ–k_p sweep <of> MFC"],
            facts={"rig": "dcmotor-sim", "runs": 3},
            pre='[campaign]\nname = "q"',
        ),
        Section(
            "Maps",
            images=[Image("RMS map", PNG, "markers as in the thesis")],
            tables=[("Best runs", pd.DataFrame({"k_p": [1.0, 2.5], "rms_error": [0.1234567, float("nan")]}))],
        ),
        Section("Damaged files", paragraphs=["a.mcap is torn"], warning=True),
    ]
    path = write_report(tmp_path / "report" / "index.html", "quickstart", "analysed", sections)
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    # no external resources: only data URIs
    assert not re.search(r'(src|href)="(?!data:)', text)
    assert "data:image/png;base64," + base64.b64encode(PNG).decode() in text
    assert "&lt;of&gt;" in text and "γ–k_p" in text
    assert "0.1235" in text and "–" in text  # float format, NaN shown as a dash
    assert 'class="warn"' in text and "name = &quot;q&quot;" in text
    assert not (tmp_path / "report" / "index.html.tmp").exists()


def _reference_rows(frame, ctx, columns, plots):
    """The table of all runs built the plain way: :func:`_cell` and :func:`_link` per value."""
    rows = []
    for rec in frame[[*columns, "log_path"]].to_dict("records"):
        cells = "".join(_cell(rec[c]) for c in columns)
        log = rec["log_path"]
        log_link = _link(ctx.out, ctx.directory / log, "log") if isinstance(log, str) else "–"
        plot = plots.get(rec["id"])
        plot_link = _link(ctx.out, plot, "plot") if plot is not None else "–"
        rows.append(f"<tr>{cells}<td>{log_link}</td><td>{plot_link}</td></tr>")
    return "".join(rows)


@pytest.mark.parametrize("out_name", ["report", "."])
def test_runs_table_matches_the_plain_per_cell_rendering(tmp_path, out_name):
    directory = tmp_path / "campaign"
    (directory / "runs").mkdir(parents=True)
    for i in (0, 1, 3):
        (directory / "runs" / f"p{i}.mcap").write_bytes(b"x")
    out = directory / out_name
    (out / "plots").mkdir(parents=True, exist_ok=True)
    (out / "plots" / "p1.png").write_bytes(PNG)
    frame = pd.DataFrame(
        {
            "seq": pd.array([0, 1, 2, 3], dtype="Int64"),
            "id": ["p0", "p1", "p2", "p3"],
            "outcome": ["completed", "aborted", "planned", "completed"],
            "controller.gamma": [10.0, 1e-7, 123456.789, 0.5],
            "law": ["sine", None, "step", "<b>"],
            "rms_error": [0.1234567, float("nan"), float("inf"), -2.0],
            "monitor": [None, "du_dt", None, None],
            "n_samples": pd.array([1000, 135, None, 1000], dtype="Int64"),
            "log_path": ["runs/p0.mcap", "runs/p1.mcap", None, "runs/p9.mcap"],  # p9: missing
        }
    )
    ctx = SimpleNamespace(out=out, directory=directory)
    plots = {"p1": out / "plots" / "p1.png", "p3": out / "plots" / "p3.png"}  # p3's plot is missing
    text = runs_table(frame, ctx, ["controller.gamma", "law"], plots)
    body = re.search(r"<tbody>(.*)</tbody>", text).group(1)
    columns = ["seq", "id", "outcome", "controller.gamma", "law", "rms_error", "monitor", "n_samples"]
    assert body == _reference_rows(frame, ctx, columns, plots)
    assert 'href="../runs/p0.mcap"' in body if out_name == "report" else 'href="runs/p0.mcap"' in body
