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
from labrunner.reproduce import checks, checks_papers, checks_twin_only, checks_walks
from labrunner.reproduce.items import QUICK_SKIP, Item, select
from labrunner.reproduce.run import CampaignResult, run_items
from labrunner.reproduce.verdict import Verdict

#: How each kind of outcome reads in the report.
_VERDICT = {True: "agrees", False: "DISAGREES", None: "not testable on the twin"}


def _check(name: str) -> Callable[[dict[str, CampaignResult]], Verdict]:
    for module in (checks, checks_twin_only, checks_walks, checks_papers):
        if hasattr(module, name):
            return getattr(module, name)
    raise AttributeError(f"no check {name!r}")


def verdict_kind(item: Item, verdicts: dict[str, Verdict]) -> str:
    """agrees | disagrees | not testable | not reproduced | not run (--quick)."""
    if not item.reproduced:
        return "not testable" if item.reason.startswith("not testable") else "not reproduced"
    if item.id not in verdicts:
        return "not run (--quick)"
    return verdicts[item.id].kind


def counts(items: Sequence[Item], verdicts: dict[str, Verdict]) -> dict[str, int]:
    """How many items of each kind (:func:`verdict_kind`)."""
    out = dict.fromkeys(("agrees", "disagrees", "not testable", "not reproduced", "not run (--quick)"), 0)
    for item in items:
        out[verdict_kind(item, verdicts)] += 1
    return out


def _item_section(
    item: Item, results: dict[str, CampaignResult] | None, verdict: Verdict | None, quick: bool
) -> Section:
    paragraphs = [f"Claim ({item.source}, {item.place}): {item.claim}"]
    if not item.reproduced:
        paragraphs.append(f"Verdict: {item.reason}")
        return Section(f"{item.id}: {item.title}", paragraphs=paragraphs)
    if item.tolerance:
        paragraphs.append(f"Tolerance: {item.tolerance}.")
    if item.calibration:
        paragraphs.append(f"Built on the source (not counted as agreement): {item.calibration}")
    if verdict is None:
        paragraphs.append(
            "Not run with --quick (its runs are the longest); run `labrunner reproduce --only "
            f"{item.id}` without --quick."
        )
        return Section(f"{item.id}: {item.title}", paragraphs=paragraphs)
    paragraphs.append(f"Measured on the twin: {verdict.measured}.")
    paragraphs.append(
        f"Verdict: {_VERDICT[verdict.agrees]}"
        + (" — the twin does not reproduce this claim." if verdict.agrees is False else ".")
    )
    skipped = [f for f in item.files if quick and f in QUICK_SKIP]
    if skipped:
        paragraphs.append("Left out in --quick: " + ", ".join(Path(f).name for f in skipped) + ".")
    results = results or {}
    files = ", ".join(f"{Path(f).name}{' (quick grid)' if quick and f in item.quick_grids else ''}" for f in results)
    images = [
        Image(f"{Path(r.file).stem}: {Path(p).stem}", Path(p).read_bytes())
        for r in results.values()
        for p in r.summary.get("maps", [])[:3]
    ]
    tables = [("Measured vs source", verdict.table)] if verdict.table is not None and len(verdict.table) else []
    return Section(
        f"{item.id}: {item.title}",
        paragraphs=[*paragraphs, f"Campaigns: {files or 'none (a computation, no twin)'}."],
        tables=tables,
        images=images,
        warning=verdict.agrees is False,
    )


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

    Returns ``{"report", "seconds", "counts": {kind: n}, "items": {id: {"verdict", "agrees", "measured"}}}``
    (``verdict``: agrees, disagrees, not testable, not reproduced or not run (--quick)).
    """
    t0 = time.perf_counter()
    items = select(tuple(only) if only else None)
    root = Path(root) if root else Path(__file__).resolve().parents[2]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    progress = stream or io.StringIO()
    results = run_items(items, root, out, quick=quick, workers=workers, stream=progress, say=say)
    verdicts = {
        item.id: _check(item.check)(results.get(item.id, {}))
        for item in items
        if item.reproduced and (item.id in results or not item.files)
    }
    sections = [_summary_section(items, verdicts, quick)]
    sections += [_item_section(item, results.get(item.id), verdicts.get(item.id), quick) for item in items]
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
        "counts": counts(items, verdicts),
        "items": {
            item.id: {
                "verdict": verdict_kind(item, verdicts),
                "agrees": verdicts[item.id].agrees if item.id in verdicts else None,
                "measured": verdicts[item.id].measured if item.id in verdicts else item.reason,
            }
            for item in items
        },
    }


def _summary_section(items: Sequence[Item], verdicts: dict[str, Verdict], quick: bool) -> Section:
    rows = [
        {
            "item": item.id,
            "source": f"{item.source}, {item.place}",
            "claim": item.claim,
            "twin": verdicts[item.id].measured if item.id in verdicts else item.reason or "not run (--quick)",
            "verdict": verdict_kind(item, verdicts),
        }
        for item in items
    ]
    n = counts(items, verdicts)
    return Section(
        "Summary",
        paragraphs=[
            f"{len(items)} items{' with reduced grids' if quick else ''}: {n['agrees']} agree with their source, "
            f"{n['disagrees']} disagree (marked DISAGREES below, with what the twin does instead), "
            f"{n['not testable']} are not testable on the twin, {n['not reproduced']} are not reproduced"
            + (f", {n['not run (--quick)']} not run with --quick" if n["not run (--quick)"] else "")
            + ". A claim the twin was calibrated on is not testable, never an agreement."
        ],
        tables=[("Claims and checks", pd.DataFrame(rows))],
        warning=n["disagrees"] > 0,
    )
