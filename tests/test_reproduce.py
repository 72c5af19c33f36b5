"""`labrunner reproduce --quick` end to end, as CI runs it (several CPU-minutes: every quick item of the
pack, the plate's Table 3 experiments included), and the checks' verdicts on the twins: the report
must say plainly where the twin disagrees with its source and which claims it cannot test."""

import json
import re
from html import escape
from pathlib import Path

import pytest

from labrunner.cli import main
from labrunner.reproduce.items import ITEMS


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["reproduce", "--quick", "--out", str(out), "--workers", "2", "--json"]) == 0
    return out, json.loads(buf.getvalue())


@pytest.mark.slow
def test_quick_pack_runs_every_quick_item_and_writes_one_report(quick):
    out, summary = quick
    assert set(summary["items"]) == {i.id for i in ITEMS}
    run = {k for k, v in summary["items"].items() if v["verdict"] in ("agrees", "disagrees") or v["agrees"] is not None}
    assert run <= {i.id for i in ITEMS if i.quick and i.reproduced}
    html = (out / "index.html").read_text(encoding="utf-8")
    for item in ITEMS:
        heading = f"{item.id}: {item.title}"
        assert heading in html or escape(heading) in html, heading
        if item.reproduced and not item.quick:  # named, with the reason it did not run
            assert f"--only {item.id}" in html
    assert html.count("data:image/png;base64,") >= 10  # the campaigns' maps, embedded
    kinds = [v["verdict"] for v in summary["items"].values()]
    assert summary["counts"] == {k: kinds.count(k) for k in summary["counts"]}
    assert len(re.findall(r"Verdict: DISAGREES", html)) == kinds.count("disagrees")  # each stated in its section


@pytest.mark.slow
def test_quick_pack_verdicts_on_the_twins(quick):
    """Where the twins reproduce their sources, where they depart, and what they cannot test (measured on the
    quick pack, 2026-12-03 and -04): the identification is calibration, never agreement."""
    _, summary = quick
    items = summary["items"]
    assert items["ident"]["verdict"] == "not testable" and "-10.6%" in items["ident"]["measured"]
    for agreeing in ("3.7", "valve-9-10"):
        assert items[agreeing]["verdict"] == "agrees", (agreeing, items[agreeing]["measured"])
    for departing in ("3.3", "3.8", "3.21", "table3"):  # Tables 3.1/3.2; Polack's stages; the sensor fault
        assert items[departing]["verdict"] == "disagrees", (departing, items[departing]["measured"])
    assert "DISAGREES" in items["table3"]["measured"] and "MBC beats MFC v" in items["table3"]["measured"]
    assert items["valve-6"]["verdict"] == "not testable" and items["3.12"]["verdict"] == "not reproduced"
    # the falsification variants (2026-12-04): A.1's falling mismatch is built in; Polack's chosen loop oscillates
    assert items["A.1"]["verdict"] == "not discriminating" and items["A.1"]["variant"] == "agrees"
    assert items["3.7"]["variant"] == "disagrees" and items["3.11"]["variant"] == "disagrees"
    for undecided in ("3.5.3", "3.24"):
        assert items[undecided]["verdict"] == "undecided", items[undecided]["measured"]
    assert items["valve-8"]["verdict"] == "disagrees" and "oscillating [DISAGREES]" in items["valve-8"]["measured"]
    assert items["calib-motor"]["verdict"] == "disagrees" and "backlash 0.25 rad" in items["calib-motor"]["measured"]
    # the valve's return path fitted on Fig. 5's saturated RMS, validated on Figs. 9/10 (2026-12-04)
    valve = items["calib-valve"]["measured"]
    assert items["calib-valve"]["verdict"] == "disagrees" and items["calib-valve"]["variant"] == "disagrees"
    assert "downstream_conductance 2.5 (l/min)/√bar" in valve and "residual 0.18 l/min" in valve
    assert "not at 14 l/min [DISAGREES]" in valve and "2.5: disagrees, 2.75: agrees, 3: agrees" in valve


ROOT = Path(__file__).resolve().parents[1]
#: How README.md and docs/fidelity.md quote the quick pack's counts (one sentence each).
COUNTS = re.compile(
    r"quick pack[^*]*\*\*(\d+) agree, (\d+) disagree, (\d+) not discriminating, (\d+) undecided, "
    r"(\d+) not testable, (\d+) not reproduced(?:, (\d+) not run)?\*\*"
)
NUMBER = re.compile(r"(?<![\w.])[−-]?\d+(?:\.\d+)?(?:\s?%)?")


def quoted_counts(text: str) -> dict[str, int]:
    m = COUNTS.search(text)
    assert m, "no quick-pack counts sentence"
    keys = ("agrees", "disagrees", "not discriminating", "undecided", "not testable", "not reproduced")
    return {**dict(zip(keys, map(int, m.groups()[:6]))), "not run (--quick)": int(m.group(7) or 0)}


def fidelity_rows(text: str) -> dict[str, list[str]]:
    """docs/fidelity.md's quick-pack table: item → [source, quick verdict, variant, what the twin does]."""
    section = text.split("## The verdicts of the quick pack", 1)[1].split("\n## ", 1)[0]
    rows = [
        line.strip("|").split(" | ") for line in section.splitlines() if line.startswith("| ") and "---" not in line
    ]
    return {r[0].strip(): [c.strip().strip("*") for c in r[1:]] for r in rows[1:]}


@pytest.mark.slow
def test_the_docs_quote_the_quick_packs_own_output(quick):
    """Every count and verdict README.md and docs/fidelity.md quote for the quick pack, and every number
    in fidelity.md's 'what the twin does' cells, is what this run of the pack measured."""
    _, summary = quick
    for doc in ("README.md", "docs/fidelity.md"):
        assert quoted_counts((ROOT / doc).read_text(encoding="utf-8")) == summary["counts"], doc
    rows = fidelity_rows((ROOT / "docs" / "fidelity.md").read_text(encoding="utf-8"))
    assert set(rows) == set(summary["items"])
    for item, (_, verdict, variant, cell) in rows.items():
        got = summary["items"][item]
        assert verdict == got["verdict"], (item, verdict, got["verdict"])
        assert variant == (got["variant"] or "—"), (item, variant, got["variant"])
        if got["verdict"] == "not run (--quick)":
            continue
        measured = " ".join(str(got[k] or "") for k in ("measured", "variant_measured"))
        for number in NUMBER.findall(cell):
            assert number.replace("−", "-") in measured.replace("−", "-"), (item, number, measured)
