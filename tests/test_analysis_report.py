"""The HTML report is one self-contained file: embedded images, tables, escaped text."""

import base64
import re

import pandas as pd

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
