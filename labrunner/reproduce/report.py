"""Compose the pack's report: one section per figure or table, a summary table first, all in one HTML file.

The maps are each campaign's own (``OUT/runs/<campaign>/report/*.png``, written by
:func:`labrunner.analysis.analyse.analyse`) and are embedded, so ``OUT/index.html`` opens alone.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from labrunner.analysis.report import Image, Section, write_report
from labrunner.reproduce import (
    checks,
    checks_calibration,
    checks_papers,
    checks_plate,
    checks_twin_only,
    checks_walks,
)
from labrunner.reproduce.items import QUICK_SKIP, Item, select
from labrunner.reproduce.run import CampaignResult, run_items
from labrunner.reproduce.verdict import KINDS, NO_REF, Judged, Ref, Verdict

#: How each kind of outcome reads in the report.
_VERDICT = {
    "agrees": "agrees",
    "disagrees": "DISAGREES",
    "not discriminating": "not discriminating",
    "undecided": "undecided",
    "not testable": "not testable on the twin",
}


def _check(name: str) -> Callable[..., Verdict]:
    for module in (checks, checks_twin_only, checks_walks, checks_papers, checks_plate, checks_calibration):
        if hasattr(module, name):
            return getattr(module, name)
    raise AttributeError(f"no check {name!r}")


def judged(item: Item, results: dict[str, CampaignResult]) -> Judged:
    """The item's check on the twin's runs and on its falsification variant (the variant's references
    passed to the check, and its files' runs in the place of the files they replace). A verdict that
    changes when the detector's undecided flags (growth alone, on runs too short for it) are dropped
    is undecided."""
    check = _check(item.check)
    twin = decided(check, results)
    variant = item.variant
    if variant is None or twin.kind not in ("agrees", "disagrees"):
        return Judged(twin, None)
    swapped = {slot: results.get(variant.files.get(slot, slot), run) for slot, run in results.items()}
    return Judged(twin, decided(check, swapped, variant.ref))


def decided(check: Callable[..., Verdict], results: dict[str, CampaignResult], ref: Ref = NO_REF) -> Verdict:
    """``check`` on ``results``, undecided where it gives another kind once the runs the detector
    could not decide (column ``undecided``) are taken as not oscillating."""
    verdict = check(results, ref=ref)
    flagged = {f: r.frame["undecided"] == 1.0 for f, r in results.items() if "undecided" in r.frame}
    n = sum(int(v.sum()) for v in flagged.values())
    if not n or verdict.kind not in ("agrees", "disagrees"):
        return verdict
    cleared = {
        f: replace(r, frame=r.frame.assign(oscillating=r.frame["oscillating"].where(~flagged[f], 0.0)))
        if f in flagged
        else r
        for f, r in results.items()
    }
    other = check(cleared, ref=ref)
    if other.kind == verdict.kind:
        return verdict
    note = (
        f"; undecided: {verdict.kind} with, {other.kind} without the detector's {n} growth flags on runs "
        "holding fewer than 3 periods of the oscillation"
    )
    return Verdict(verdict.measured + note, None, verdict.table, undecided=True)


def verdict_kind(item: Item, verdicts: dict[str, Judged]) -> str:
    """One of :data:`~labrunner.reproduce.verdict.KINDS`, or "not run (--quick)"."""
    if not item.reproduced:
        return "not testable" if item.reason.startswith("not testable") else "not reproduced"
    if item.id not in verdicts:
        return "not run (--quick)"
    return verdicts[item.id].kind


def counts(items: Sequence[Item], verdicts: dict[str, Judged]) -> dict[str, int]:
    """How many items of each kind (:func:`verdict_kind`)."""
    out = dict.fromkeys((*KINDS, "not run (--quick)"), 0)
    for item in items:
        out[verdict_kind(item, verdicts)] += 1
    return out


def _item_section(
    item: Item, results: dict[str, CampaignResult] | None, judgement: Judged | None, quick: bool
) -> Section:
    paragraphs = [f"Claim ({item.source}, {item.place}): {item.claim}"]
    if not item.reproduced:
        paragraphs.append(f"Verdict: {item.reason}")
        return Section(f"{item.id}: {item.title}", paragraphs=paragraphs)
    if item.tolerance:
        paragraphs.append(f"Tolerance: {item.tolerance}.")
    if item.calibration:
        paragraphs.append(f"Built on the source (not counted as agreement): {item.calibration}")
    if judgement is None:
        paragraphs.append(
            "Not run with --quick (its runs are the longest); run `labrunner reproduce --only "
            f"{item.id}` without --quick."
        )
        return Section(f"{item.id}: {item.title}", paragraphs=paragraphs)
    verdict, kind = judgement.twin, judgement.kind
    paragraphs.append(f"Measured on the twin: {verdict.measured}.")
    paragraphs.append(_variant_line(item, judgement))
    paragraphs.append(
        f"Verdict: {_VERDICT[kind]}" + (" — the twin does not reproduce this claim." if kind == "disagrees" else ".")
    )
    if item.flips:
        paragraphs.append(f"Quick vs full grids: {item.flips}")
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
        warning=kind == "disagrees",
    )


def _variant_line(item: Item, judgement: Judged) -> str:
    """What the falsification variant is, what the check gave on it, and what that means for the verdict."""
    if item.variant is None:
        return "No falsification variant: the check is not shown to discriminate."
    twin, variant = judgement.twin.kind, judgement.variant.kind if judgement.variant else "not run"
    text = f"Falsification variant ({item.variant.what}): the check {variant} (on the twin: {twin})"
    if twin not in ("agrees", "disagrees"):
        return text + "; the variant is not judged where the twin's verdict is not agrees or disagrees."
    if judgement.kind == "not discriminating":
        return text + (
            f"; it gives '{variant}' on a variant built to fail the claim, so it does not tell the twin from it: "
            f"measured on the variant: {judgement.variant.measured if judgement.variant else '—'}."
        )
    return text + "."


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

    Returns ``{"report", "seconds", "counts": {kind: n}, "items": {id: {"verdict", "agrees", "measured",
    "twin", "variant", "variant_measured"}}}`` (``verdict``: a kind of :data:`~labrunner.reproduce.verdict.KINDS`
    or not run (--quick); ``twin``, ``variant``: the check's kind on the twin and on the falsification variant).
    """
    t0 = time.perf_counter()
    items = select(tuple(only) if only else None)
    root = Path(root) if root else Path(__file__).resolve().parents[2]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    progress = stream or io.StringIO()
    results = run_items(items, root, out, quick=quick, workers=workers, stream=progress, say=say)
    verdicts = {
        item.id: judged(item, results.get(item.id, {}))
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
                "agrees": verdicts[item.id].twin.agrees if item.id in verdicts else None,
                "measured": verdicts[item.id].twin.measured if item.id in verdicts else item.reason,
                "twin": verdicts[item.id].twin.kind if item.id in verdicts else None,
                "variant": _variant_kind(verdicts.get(item.id)),
                "variant_measured": _variant_measured(verdicts.get(item.id)),
            }
            for item in items
        },
    }


def _variant_kind(judgement: Judged | None) -> str | None:
    return judgement.variant.kind if judgement and judgement.variant else None


def _variant_measured(judgement: Judged | None) -> str | None:
    return judgement.variant.measured if judgement and judgement.variant else None


def _summary_section(items: Sequence[Item], verdicts: dict[str, Judged], quick: bool) -> Section:
    rows = [
        {
            "item": item.id,
            "source": f"{item.source}, {item.place}",
            "claim": item.claim,
            "twin": verdicts[item.id].twin.measured if item.id in verdicts else item.reason or "not run (--quick)",
            "check on the twin": verdicts[item.id].twin.kind if item.id in verdicts else "",
            "check on its variant": _variant_kind(verdicts.get(item.id)) or "",
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
            f"{n['not discriminating']} are not discriminating (the check agrees on a variant built to fail the "
            f"claim), {n['undecided']} are undecided, "
            f"{n['not testable']} are not testable on the twin, {n['not reproduced']} are not reproduced"
            + (f", {n['not run (--quick)']} not run with --quick" if n["not run (--quick)"] else "")
            + ". A claim the twin was calibrated on is not testable, never an agreement. Each item's check is "
            "also applied to a falsification variant (a reference or twin deliberately wrong in the way the claim "
            "is about): an agreement counts only where the variant disagrees."
        ],
        tables=[("Claims and checks", pd.DataFrame(rows))],
        warning=n["disagrees"] > 0,
    )
