"""Run the pack's campaigns (full or ``--quick``) and analyse each: the I/O half of ``labrunner reproduce``.

A ``--quick`` variant of a campaign file is its text with the ``[grid]`` section replaced by the
item's quick grid and ``-quick`` appended to its name, written to ``OUT/campaigns/``; the rig is
found by name as for any campaign. Each campaign runs into ``OUT/runs/<name>`` (resumed when that
directory exists: a second ``reproduce`` only re-analyses) and is analysed into its ``report/``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import pandas as pd

from labrunner.errors import InvalidParameter
from labrunner.reproduce.items import QUICK_SKIP, Item

_GRID = re.compile(r"^\[grid\][^\n]*\n(?:(?!\[)[^\n]*\n?)*", re.MULTILINE)
_NAME = re.compile(r'^(name\s*=\s*")([^"]+)(")', re.MULTILINE)


@dataclass(frozen=True)
class CampaignResult:
    """One analysed campaign: its file, directory, metrics table, analysis summary and grid parameters."""

    file: str  # as the item names it
    directory: Path
    frame: pd.DataFrame
    summary: dict[str, Any]
    parameters: list[dict[str, Any]]  # per point in grid order (seq), list values included


def variant_text(text: str, grid: str, suffix: str = "-quick") -> str:
    """``text`` with its ``[grid]`` section replaced by ``grid`` and ``suffix`` appended to its name."""
    if not _GRID.search(text):
        raise InvalidParameter("grid", "a quick grid needs a campaign file with a [grid] section")
    out = _GRID.sub(lambda _: f"[grid]\n{grid.strip()}\n\n", text, count=1)
    return _NAME.sub(lambda m: f"{m.group(1)}{m.group(2)}{suffix}{m.group(3)}", out, count=1)


def campaign_file(item: Item, file: str, root: Path, out: Path, quick: bool) -> Path:
    """The campaign file to run for ``file`` of ``item``: the pack's own, or its quick variant."""
    source = root / file
    grid = item.quick_grids.get(file) if quick else None
    if grid is None:
        return source
    target = out / "campaigns" / source.name
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(variant_text(source.read_text(encoding="utf-8"), grid), encoding="utf-8")
    return target


def run_file(path: Path, directory: Path, *, workers: int | None, stream: TextIO | None) -> CampaignResult:
    """Run (or resume) one campaign into ``directory`` and analyse it."""
    from labrunner.analysis.analyse import analyse
    from labrunner.campaign import runner, spec
    from labrunner.campaign.ledger import LEDGER_NAME

    opts = runner.Options(workers=workers, stream=stream)
    if (directory / LEDGER_NAME).exists():
        runner.resume(directory, opts)
    else:
        runner.start(path, directory, opts)
    summary = analyse(directory, directory / "report", workers=workers, recompute=stale_detector(directory))
    frame = pd.read_parquet(directory / "report" / "metrics.parquet").sort_values("seq").reset_index(drop=True)
    campaign = spec.load(directory / runner.CAMPAIGN_COPY, root=spec.project_root(path))
    parameters = [] if campaign.guided is not None else [params for params, _ in campaign.points()]
    return CampaignResult(str(path), directory, frame, summary, parameters)


def stale_detector(directory: Path) -> bool:
    """Whether runs of ``directory`` were committed by an older oscillation detector (their metrics lack
    one of its columns or carry another ``detector_version``): their metrics are then recomputed from
    the logs, so that every run of the pack is judged by the same detector."""
    import json

    from labrunner.campaign.ledger import Ledger
    from labrunner.oscillation import DETECTOR_METRICS, VERSION

    with Ledger.open_readonly(directory) as ledger:
        for row in ledger.rows(("done", "aborted")):
            metrics = json.loads(row["metrics_json"]) if row["metrics_json"] else {}
            if "oscillating" in metrics and (
                not set(DETECTOR_METRICS) <= set(metrics) or metrics["detector_version"] != VERSION
            ):
                return True
    return False


def run_items(
    items: Sequence[Item],
    root: Path,
    out: Path,
    *,
    quick: bool,
    workers: int | None = None,
    stream: TextIO | None = None,
    say: Callable[[str], None] = lambda _: None,
) -> dict[str, dict[str, CampaignResult]]:
    """Run every campaign of ``items``; ``{item id: {file: result}}`` (files ``--quick`` leaves out absent;
    items that are not reproduced absent). A campaign several items share runs and is analysed once."""
    from labrunner.analysis.analyse import prepare_drawing

    prepare_drawing(workers)  # once for the ~30 analyses' drawing children
    results: dict[str, dict[str, CampaignResult]] = {}
    done: dict[Path, CampaignResult] = {}
    for item in items:
        if (quick and not item.quick) or not item.reproduced:
            continue
        results[item.id] = {}
        for file in item.files:
            if quick and file in QUICK_SKIP:
                continue
            path = campaign_file(item, file, root, out, quick)
            if path not in done:
                name = path.stem + ("-quick" if path != root / file else "")
                say(f"{item.id}: {file}{' (quick grid)' if path != root / file else ''}")
                done[path] = run_file(path, out / "runs" / name, workers=workers, stream=stream)
            results[item.id][file] = done[path]
    return results
