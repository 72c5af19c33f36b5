"""Compose the pack's report: one section per figure or table, a summary table first, all in one HTML file.

The maps are each campaign's own (``OUT/runs/<campaign>/report/*.png``, written by
:func:`labrunner.analysis.analyse.analyse`) and are embedded, so ``OUT/index.html`` opens alone.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from labrunner.analysis.report import Image, Section, write_report
from labrunner.reproduce import checks, checks_papers
from labrunner.reproduce.checks import Verdict
from labrunner.reproduce.items import QUICK_SKIP, Item, select
from labrunner.reproduce.run import CampaignResult, run_items

_VERDICT = {True: "agrees", False: "DISAGREES", None: "no yes/no answer"}


def _check(name: str) -> Callable[[dict[str, CampaignResult]], Verdict]:
    return getattr(checks, name, None) or getattr(checks_papers, name)


def _item_section(
    item: Item, results: dict[str, CampaignResult] | None, verdict: Verdict | None, quick: bool
) -> Section:
    paragraphs = [f"Claim ({item.source}): {item.claim}"]
    if results is None:
        paragraphs.append(
            "Not run with --quick (its runs are the longest); run `labrunner reproduce --only "
            f"{item.id}` without --quick."
        )
        return Section(f"{item.id}: {item.title}", paragraphs=paragraphs)
    assert verdict is not None
    paragraphs.append(f"Measured on the twin: {verdict.measured}.")
    paragraphs.append(
        f"Verdict: {_VERDICT[verdict.agrees]}"
        + (" — the twin does not reproduce this claim." if verdict.agrees is False else ".")
    )
    skipped = [f for f in item.files if quick and f in QUICK_SKIP]
    if skipped:
        paragraphs.append("Left out in --quick: " + ", ".join(Path(f).name for f in skipped) + ".")
    files = ", ".join(f"{Path(f).name}{' (quick grid)' if quick and f in item.quick_grids else ''}" for f in results)
    images = [
        Image(f"{Path(r.file).stem}: {Path(p).stem}", Path(p).read_bytes())
        for r in results.values()
        for p in r.summary.get("maps", [])[:3]
    ]
    tables = [("Measured vs source", verdict.table)] if verdict.table is not None and len(verdict.table) else []
    return Section(
        f"{item.id}: {item.title}",
        paragraphs=[*paragraphs, f"Campaigns: {files}."],
        tables=tables,
        images=images,
        warning=verdict.agrees is False,
    )


def _guided_section(out: Path, workers: int | None, stream: TextIO | None) -> tuple[Section, dict[str, Any] | None]:
    """Guideline 2 vs Polack et al. run as guided (adaptive) campaigns, when that module is present."""
    try:
        from labrunner.campaign.guided_report import compare_guideline2_polack
    except ImportError:
        return Section(
            "Guideline 2 vs Polack et al., guided campaigns",
            paragraphs=[
                "Pending: the guided campaigns (labrunner.campaign.guided_report) are not in this build, so the "
                "adaptive walks' step counts are not reported here; see item 3.21-3.23 for the walks replayed on grids."
            ],
        ), None
    counts = compare_guideline2_polack(out / "guided", workers=workers, stream=stream)
    g2, pol = counts["guideline2"], counts["polack"]
    table = pd.DataFrame(
        {
            "thesis": [counts["thesis"].get("polack"), counts["thesis"].get("guideline2")],
            "twin": [pol["runs"], g2["steps_to_polack_rms"]],
        },
        index=["Polack et al.", "Guideline 2"],
    )
    return Section(
        "Guideline 2 vs Polack et al., guided campaigns",
        paragraphs=[
            f"Polack et al.: {pol['runs']} runs ({pol['feed_forward']} feed-forward + {pol['feedback']} feedback); "
            f"Guideline 2 reaches Polack's RMS after {g2['steps_to_polack_rms']} steps: ratio {counts['ratio']:.2f} "
            "(thesis 107 / 54 ≈ 2)."
        ],
        tables=[("Step counts", table)],
    ), counts


def reproduce(
    out: str | Path,
    *,
    quick: bool = False,
    only: Sequence[str] | None = None,
    workers: int | None = None,
    root: str | Path | None = None,
    stream: TextIO | None = None,
    say: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Run the pack (or the items ``only`` names) into ``out`` and write ``out/index.html``.

    Returns ``{"report", "items": {id: {"agrees", "measured"}}, "seconds"}``.
    """
    t0 = time.perf_counter()
    items = select(tuple(only) if only else None)
    root = Path(root) if root else Path(__file__).resolve().parents[2]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    progress = stream or io.StringIO()
    results = run_items(items, root, out, quick=quick, workers=workers, stream=progress, say=say)
    verdicts = {item.id: _check(item.check)(results[item.id]) for item in items if item.id in results}
    sections = [_summary_section(items, verdicts, quick)]
    sections += [_item_section(item, results.get(item.id), verdicts.get(item.id), quick) for item in items]
    guided = None
    if not only or "3.21-3.23" in (only or ()):
        say("guided: Guideline 2 vs Polack et al.")
        section, guided = _guided_section(out, workers, progress)
        sections.append(section)
    seconds = time.perf_counter() - t0
    mode = "--quick (reduced grids)" if quick else "full grids"
    report = write_report(
        out / "index.html",
        "labrunner reproduce",
        f"The campaign pack on the simulated twins, {mode}, {seconds:.0f} s",
        sections,
    )
    return {
        "report": str(report),
        "seconds": seconds,
        "guided": guided,
        "items": {
            k: {"agrees": None if v.agrees is None else bool(v.agrees), "measured": v.measured}
            for k, v in verdicts.items()
        },
    }


def _summary_section(items: Sequence[Item], verdicts: dict[str, Verdict], quick: bool) -> Section:
    rows = [
        {
            "item": item.id,
            "source": item.source,
            "claim": item.claim,
            "twin": verdicts[item.id].measured if item.id in verdicts else "not run (--quick)",
            "verdict": _VERDICT[verdicts[item.id].agrees] if item.id in verdicts else "—",
        }
        for item in items
    ]
    n_bad = sum(v.agrees is False for v in verdicts.values())
    return Section(
        "Summary",
        paragraphs=[
            f"{len(verdicts)} of {len(items)} items run{' with reduced grids' if quick else ''}; "
            f"{sum(v.agrees is True for v in verdicts.values())} agree with their source, {n_bad} do not "
            "(marked DISAGREES below, with what the twin does instead)."
        ],
        tables=[("Claims and checks", pd.DataFrame(rows))],
        warning=n_bad > 0,
    )
