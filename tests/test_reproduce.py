"""`labrunner reproduce --quick` end to end, as CI runs it (several CPU-minutes: every quick item of the
pack, the plate's Table 3 experiments included), and the checks' verdicts on the twins: the report
must say plainly where the twin disagrees with its source and which claims it cannot test."""

import contextlib
import fcntl
import io
import json
import os
import re
from html import escape
from pathlib import Path

import pytest

from labrunner.cli import main
from labrunner.reproduce.items import ITEMS, QUICK_SKIP, Item
from labrunner.reproduce.run import campaign_file

ROOT = Path(__file__).resolve().parents[1]


def _campaigns() -> dict[str, tuple[Item, str]]:
    """The quick pack's campaigns in the pack's order: {its directory under OUT/runs: (item, file)}, each
    once, with the first item naming it and the directory's name as ``run_items`` gives them."""
    out: dict[str, tuple[Item, str]] = {}
    for item in ITEMS:
        for file in item.files if item.quick and item.reproduced else ():
            if file not in QUICK_SKIP:
                out.setdefault(Path(file).stem + ("-quick" if file in item.quick_grids else ""), (item, file))
    return out


CAMPAIGNS = _campaigns()


@pytest.fixture(scope="module")
def pack(tmp_path_factory) -> Path:
    """The quick pack's output folder, one per session: every pytest-xdist worker sees the same one
    (the workers' base temporary folders share a parent), so that its campaigns are spread over them."""
    base = tmp_path_factory.getbasetemp()
    out = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "reproduce-quick"
    (out / "locks").mkdir(parents=True, exist_ok=True)
    return out


@contextlib.contextmanager
def _locked(out: Path, name: str, wait: bool = True):
    """An exclusive lock between the workers (released when the file closes or the worker dies); yields
    False without it where ``wait`` is False and another worker holds it."""
    with open(out / "locks" / f"{name}.lock", "w") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        yield True


def _campaign(out: Path, name: str, wait: bool = True) -> dict | None:
    """Run the pack's campaign ``name`` into ``OUT/runs/name`` as ``reproduce --quick`` would (the same
    file, grid and directory), unless a worker already has; its outcome {complete, counts} (None where
    ``wait`` is False and another worker is running it). The report (the fixture below) then resumes it,
    which finds nothing to run, and analyses it."""
    from labrunner.campaign import runner

    done = out / "runs" / f"{name}.outcome.json"
    with _locked(out, name, wait) as mine:
        if not mine:
            return None
        if not done.exists():
            item, file = CAMPAIGNS[name]
            path = campaign_file(item, file, ROOT, out, quick=True)
            directory = out / "runs" / name
            opts = runner.Options(workers=1, stream=io.StringIO())
            outcome, _ = runner.resume(directory, opts) if directory.exists() else runner.start(path, directory, opts)
            result = {"complete": outcome.complete, "counts": outcome.counts}
            if not outcome.complete:
                return result
            done.write_text(json.dumps(result), encoding="utf-8")
        return json.loads(done.read_text(encoding="utf-8"))


@pytest.mark.slow
@pytest.mark.parametrize("name", CAMPAIGNS)
def test_each_campaign_of_the_quick_pack_runs_to_its_end(pack, name):
    """One campaign of the pack a test, so that pytest-xdist spreads the pack's ~320 CPU-seconds of runs
    (2026-12-04) over its workers instead of one worker running them in turn."""
    outcome = _campaign(pack, name)
    assert outcome["complete"] and sum(outcome["counts"].values()) > 0, outcome


@pytest.fixture(scope="module")
def quick(pack):
    """``labrunner reproduce --quick`` on the campaigns above (run here when no other worker has), once a
    session: a worker that finds the report written reads its summary."""
    for name in CAMPAIGNS:  # first those no other worker is running, then wait for the rest
        _campaign(pack, name, wait=False)
    for name in CAMPAIGNS:
        assert _campaign(pack, name)["complete"], name
    summary = pack / "summary.json"
    with _locked(pack, "report"):
        if not summary.exists():
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                assert main(["reproduce", "--quick", "--out", str(pack), "--workers", "2", "--json"]) == 0
            summary.write_text(buf.getvalue(), encoding="utf-8")
    # the report ran no campaign of its own: it found each of the ones above where it looks for it
    assert sorted(p.name for p in (pack / "runs").iterdir() if p.is_dir()) == sorted(CAMPAIGNS)
    return pack, json.loads(summary.read_text(encoding="utf-8"))


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
