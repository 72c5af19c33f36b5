"""Guided campaigns in the ledger: planning, the round loop, replay, status and ``--dry-run``.

Each round's points are ordinary ledger rows (``planned`` → … → terminal), appended in one
transaction (:meth:`~labrunner.campaign.ledger.Ledger.add_points`) with the same stable ids as grid
points, and run by the ordinary :class:`~labrunner.campaign.scheduler.Scheduler`. The procedure's
state is never stored: before every round the plan is replayed from the terminal rows
(:func:`labrunner.campaign.guided.advance`), so a runner killed at any moment resumes with the same
decisions — a round cut short is finished by the ordinary recovery and scheduler, a round not yet
written is proposed again, identically.
"""

from __future__ import annotations

import contextlib
import hashlib
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from labrunner.campaign.grid import canonical_json, point_id
from labrunner.campaign.guided import Advance, Observation, advance
from labrunner.campaign.ledger import TERMINAL, Ledger
from labrunner.campaign.scheduler import Outcome
from labrunner.campaign.spec import Campaign, PlannedPoint


def check_points(campaign: Campaign, points: Sequence[Mapping[str, Any]], first_seq: int = 0) -> list[PlannedPoint]:
    """Statically check points as :func:`labrunner.campaign.spec.plan` checks a grid; their ids are
    those of the points as proposed, their parameters include ``[derived]`` values."""
    from labrunner.campaign.checks import batch_key

    checker = static_checker(campaign)
    checked: dict[int, tuple[dict[str, Any], dict[str, Any], float]] = {}
    for n, point in enumerate(points):
        params, config = campaign.expand(dict(point))
        for (seq, p, c), duration in checker.add(n, params, config):
            checked[seq] = (p, c, duration)
    for (seq, p, c), duration in checker.flush():
        checked[seq] = (p, c, duration)
    out = []
    for n, point in enumerate(points):
        params, config, duration = checked[n]
        config["campaign"]["duration"] = duration
        out.append(
            PlannedPoint(
                first_seq + n, point_id(campaign.name, point), params, batch_key(campaign.rig, config, checker.split)
            )
        )
    return out


def static_checker(campaign: Campaign):
    """The grid campaigns' :class:`~labrunner.campaign.checks.StaticChecker` for ``campaign``'s rig file."""
    from labrunner.campaign.checks import StaticChecker

    return StaticChecker(campaign.rig_config)


def plan(campaign: Campaign) -> tuple[list[PlannedPoint], str]:
    """The first round's points and the plan checksum (procedure, base configuration, the checked
    extreme points of the search space and the first round)."""
    procedure = campaign.guided
    corners = check_points(campaign, procedure.corners())
    first = check_points(campaign, list(advance(procedure, campaign.name, {}).next))
    digest = hashlib.sha256(
        canonical_json(
            {
                "name": campaign.name,
                "rig": campaign.rig,
                "procedure": procedure.identity(),
                "base": campaign.resolve({}),
                "points": [[p.parameters, p.batch_key] for p in (*corners, *first)],
            }
        ).encode()
    )
    return first, digest.hexdigest()


def observations(rows: Sequence[Mapping[str, Any]]) -> dict[str, Observation]:
    """Terminal ledger rows as the observations a plan is sent (point id → observation)."""
    import json

    def flagged(row: Mapping[str, Any]) -> bool:  # the oscillation detector's verdict at run time
        text = row["metrics_json"] if "metrics_json" in row.keys() else None
        metrics = json.loads(text) if text else {}
        return metrics.get("oscillating") == 1.0

    return {
        r["id"]: Observation(
            r["id"], json.loads(r["parameters"]), r["outcome"], r["rms_error"], r["input_energy"], flagged(r)
        )
        for r in rows
        if r["state"] in TERMINAL
    }


def replay(campaign: Campaign, rows: Sequence[Mapping[str, Any]]) -> Advance:
    """The procedure's state rebuilt from ledger rows alone."""
    return advance(campaign.guided, campaign.name, observations(rows))


def execute(campaign: Campaign, ledger: Ledger, run_round: Callable[[], Outcome], signals: Any = None) -> Outcome:
    """Replay, append the next round's new points, run the planned rows; until the plan ends, Ctrl-C,
    or a stop (rig failure). ``run_round`` is the scheduler's ``run``; ``signals`` the scheduler's
    :class:`~labrunner.campaign.scheduler.StopSignals` (one counter for rounds and batches)."""
    from labrunner.campaign.scheduler import StopSignals

    total = Outcome()
    t0 = time.monotonic()
    with contextlib.nullcontext(signals) if signals is not None else StopSignals() as signals:
        _rounds(campaign, ledger, run_round, total, signals)  # Ctrl-C between rounds: stop before the next
    total.elapsed_s = time.monotonic() - t0
    total.counts = ledger.counts()
    return total


def _rounds(campaign: Campaign, ledger: Ledger, run_round: Callable[[], Outcome], total: Outcome, signals: Any) -> None:
    while not signals.count:
        rows = ledger.rows()
        state = replay(campaign, rows)
        if state.result is not None:
            break
        present = {r["id"] for r in rows}
        new = [p for p in state.next if point_id(campaign.name, p) not in present]
        if new:
            ledger.add_points((p.id, p.parameters, p.batch_key) for p in check_points(campaign, new, len(rows)))
        out = run_round()
        total.committed += out.committed
        total.interrupted |= out.interrupted
        total.abandoned |= out.abandoned
        total.stop_reason = total.stop_reason or out.stop_reason
        total.interrupted |= bool(out.signals)  # a Ctrl-C while the round's last batch ran
        if total.interrupted or out.abandoned or out.stop_reason:
            break
        if out.committed == 0:  # the plan waits on points the scheduler will not run (claimed elsewhere?)
            total.stop_reason = f"round of {len(state.next)} point(s) ran nothing; resume to settle them"
            break
    total.interrupted |= bool(signals.count)


def summary(campaign: Campaign, rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """What a guided campaign has decided so far (``status --json`` and the analysis)."""
    procedure = campaign.guided
    state = replay(campaign, rows)
    out: dict[str, Any] = {
        "procedure": procedure.name,
        "description": procedure.describe(),
        "max_runs": procedure.max_runs(),
        "runs": state.runs,
        "finished": state.result is not None,
        "stages": state.stage_counts(),
        "waiting_on": len(state.next),
        "stage": state.stage or None,
    }
    if state.result is not None:
        chosen = state.result.chosen
        out.update(
            reason=state.result.reason,
            detail=dict(state.result.detail),
            chosen=None
            if chosen is None
            else {
                "id": chosen.id,
                "params": dict(chosen.params),
                "status": chosen.status,
                "rms_error": chosen.rms_error,
                "step": next(n for n, s in enumerate(state.walk) if s.observation.id == chosen.id) + 1,
            },
        )
    return out


def status_lines(summary: dict[str, Any]) -> list[str]:
    """The plain-text ``status`` lines of a guided campaign's summary."""
    if "note" in summary:
        return [f"  guided ({summary['procedure']}): {summary['note']}"]
    stages = "; ".join(f"{k}: {v['runs']} runs" for k, v in summary["stages"].items()) or "no run yet"
    lines = [
        f"  guided: {summary['description']}",
        f"  {summary['runs']} of at most {summary['max_runs']} runs ({stages})",
    ]
    if summary["finished"]:
        chosen = summary.get("chosen")
        if not chosen:
            lines.append(f"  finished: {summary['reason']}")
        else:
            values = ", ".join(
                f"{k.split('.')[-1]} = {v:.5g}" for k, v in chosen["params"].items() if isinstance(v, float)
            )
            rms = f", RMS(e) = {chosen['rms_error']:.4g}" if chosen["rms_error"] is not None else ""
            lines.append(f"  finished ({summary['reason']}): chose step {chosen['step']}: {values}{rms}")
    else:
        lines.append(f"  open stage {summary['stage']!r}: waits on {summary['waiting_on']} point(s)")
    return lines


def stored_summary(meta: Mapping[str, str], rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """:func:`summary` of the campaign a ledger keeps (``meta``), or why it cannot be given (``status``)."""
    campaign, note = _stored_campaign(meta)
    if campaign is None:
        return {"procedure": meta.get("guided"), "note": note}
    return summary(campaign, rows)


def _stored_campaign(meta: Mapping[str, str]) -> tuple[Campaign | None, str]:
    """The guided campaign kept in a ledger's ``meta`` (without the analysis' heavy imports)."""
    from labrunner.campaign import spec
    from labrunner.errors import LabrunnerError

    source = meta.get("campaign_path")
    try:
        campaign = spec.from_text(meta.get("campaign_file", ""), source_path=Path(source) if source else None)
    except LabrunnerError as exc:
        return None, f"the campaign file could not be loaded again: {exc}"
    return (campaign, "") if campaign.guided is not None else (None, "the stored campaign is not guided")


def directory_state(directory: str | Path) -> tuple[Campaign, Advance, dict[str, Any]]:
    """(campaign, replayed state, summary) of a guided campaign directory (reads only)."""
    from labrunner.errors import CampaignError

    with Ledger.open_readonly(Path(directory)) as ledger:
        rows = [dict(r) for r in ledger.rows()]
        meta = ledger.meta()
    campaign, note = _stored_campaign(meta)
    if campaign is None:
        raise CampaignError(f"{directory} holds no guided campaign: {note}")
    return campaign, replay(campaign, rows), summary(campaign, rows)


def dry_run(campaign: Campaign, first: list[PlannedPoint], slots: int) -> str:
    """``--dry-run`` text: guided, the procedure, the maximum number of runs, an estimated time."""
    import json

    from labrunner.campaign.runner import _estimate_sim

    procedure = campaign.guided
    n = procedure.max_runs()
    _, fs, duration, *_ = json.loads(first[0].batch_key)
    lines = [
        f"campaign {campaign.name}: guided ({procedure.name}) on rig {campaign.rig!r}, at most {n} runs",
        f"  {procedure.describe()}",
        f"  first round: {len(first)} point(s) × {duration:g} s at {fs:g} Hz; later rounds follow from the outcomes",
    ]
    if campaign.rig_info.simulated:
        parallel = slots if len(first) > 1 else 1  # a walk runs one point per round
        per_run = _estimate_sim(campaign, first, 1, len(first)) / len(first)
        rounds = n if len(first) == 1 else -(-n // len(first))  # each round costs a start-up of ~0.2 s
        lines.append(
            f"  estimated time ≤ {per_run * n / parallel + 0.2 * rounds:.0f} s for {n} runs on {parallel} worker(s) "
            f"(≤ {n * duration:g} s of simulated time)"
        )
    else:
        lines.append(f"  estimated time ≤ {n * (duration + 2.0):.0f} s on the real rig (one run at a time)")
    return "\n".join(lines)
