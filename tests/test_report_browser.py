"""The HTML report of a real campaign in a real browser: headless Chromium (tests/browser_support.py)
sorts and filters the runs table, and every image and link of the page must resolve with no
console error. The expected orders and counts come from metrics.csv, which the report's table
is written from, read with pandas."""

from __future__ import annotations

import json
from pathlib import Path
from urllib.parse import unquote, urlsplit

import browser_support
import pandas as pd
import pytest
from browser_support import open_page
from test_campaign_support import campaign_text, cli, write

GRID = '"controller.gamma" = { log10 = [1.5, 3.0], num = 3 }\n"controller.k_p" = { log10 = [0.0, 2.5], num = 3 }'
N = 9  # points

ROWS = "[...document.querySelector('table.sortable').tBodies[0].rows]"


def _column(page, name: str) -> list[str]:
    """The shown rows' cells of column ``name`` of the runs table, top to bottom."""
    return page.evaluate(
        f"(() => {{ const t = document.querySelector('table.sortable');"
        f" const i = [...t.tHead.rows[0].cells].findIndex(c => c.textContent === {json.dumps(name)});"
        f" return {ROWS}.filter(r => !r.hidden).map(r => r.cells[i].textContent); }})()"
    )


def _click_header(page, name: str) -> None:
    page.evaluate(
        "[...document.querySelector('table.sortable').tHead.rows[0].cells]"
        f".find(c => c.textContent === {json.dumps(name)}).click()"
    )


def _type_filter(page, text: str) -> None:
    """Focus the filter box, clear it and type ``text`` as keystrokes would (CDP Input.insertText)."""
    page.evaluate("(() => { const b = document.querySelector('input.filter'); b.focus(); b.select(); })()")
    page.call("Input.dispatchKeyEvent", type="keyDown", key="Backspace", code="Backspace", windowsVirtualKeyCode=8)
    page.call("Input.dispatchKeyEvent", type="keyUp", key="Backspace", code="Backspace", windowsVirtualKeyCode=8)
    if text:
        page.call("Input.insertText", text=text)


@pytest.mark.slow
def test_the_report_sorts_filters_and_resolves_every_link_and_image_in_chromium(project, tmp_path):
    write(project / "web.toml", campaign_text(name="web", grid=GRID, duration=2.0))
    ran = cli("run", "web.toml", "--workers", "1", cwd=project)
    assert ran.returncode == 0, ran.stderr
    analysed = cli("analyse", "data/web", "--workers", "1", "--plot", "aborted", cwd=project)
    assert analysed.returncode == 0, analysed.stderr
    report = project / "data" / "web" / "report"
    table = pd.read_csv(report / "metrics.csv")
    assert len(table) == N and set(table["outcome"]) >= {"completed", "aborted"}  # both, so that filtering shows

    with open_page((report / "index.html").as_uri(), tmp_path / "profile") as page:
        assert page.evaluate(f"{ROWS}.length") == N

        # sorting: ascending, then descending, by a metric; the dashes of runs without it stay last
        by_rms = table.sort_values("rms_error", na_position="last", kind="stable")
        _click_header(page, "rms_error")
        assert _column(page, "id") == by_rms["id"].tolist()
        _click_header(page, "rms_error")
        shown = _column(page, "id")
        numbered = by_rms["rms_error"].notna().sum()
        assert shown[:numbered] == by_rms["id"].tolist()[:numbered][::-1]  # the runs with a value, reversed
        _click_header(page, "id")  # text
        assert _column(page, "id") == sorted(table["id"])

        # filtering: the words typed, each found in some cell of every row shown
        _type_filter(page, "aborted")
        aborted = table[table["outcome"] == "aborted"]
        assert sorted(_column(page, "id")) == sorted(aborted["id"])
        assert page.evaluate("document.querySelector('input.filter + span').textContent").strip() == (
            f"{len(aborted)} of {N} rows"
        )
        one = table["id"].iloc[5]
        _type_filter(page, f"{one[:6].upper()} {table['outcome'].iloc[5]}")  # case-blind, words in any order
        assert _column(page, "id") == [one]
        _type_filter(page, "no row has this")
        assert _column(page, "id") == []
        _type_filter(page, "")
        assert len(_column(page, "id")) == N

        # every image decoded, every link pointing at a file that exists
        images = page.evaluate("[...document.images].map(i => [i.alt, i.complete && i.naturalWidth > 0])")
        assert images and all(ok for _, ok in images), images
        hrefs = page.evaluate("[...document.querySelectorAll('a[href]')].map(a => a.href)")
        plots = [h for h in hrefs if h.endswith(".png")]
        assert len(plots) >= len(aborted)  # --plot aborted: one plot each, linked from the table
        logs = {Path(unquote(urlsplit(h).path)).name for h in hrefs if h.endswith(".mcap")}
        assert logs == {f"{i}.mcap" for i in table["id"]}  # every run's log, from the table
        missing = [h for h in hrefs if urlsplit(h).scheme != "file" or not Path(unquote(urlsplit(h).path)).is_file()]
        assert not missing, missing

        assert page.errors() == []


def test_a_missing_chromium_skips_here_and_fails_under_ci(monkeypatch):
    monkeypatch.setattr(browser_support.shutil, "which", lambda name: None)
    monkeypatch.delenv("LABRUNNER_CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="apt-get install -y chromium"):
        browser_support.chromium()
    monkeypatch.setenv("LABRUNNER_CI", "1")
    with pytest.raises(pytest.fail.Exception, match="no Chromium"):
        browser_support.chromium()
