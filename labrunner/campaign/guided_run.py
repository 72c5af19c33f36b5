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
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from labrunner.campaign.grid import point_id
from labrunner.campaign.guided import Advance, Observation, Oracle, advance
from labrunner.campaign.ledger import TERMINAL, Ledger
from labrunner.campaign.scheduler import Outcome
from labrunner.campaign.spec import Campaign, check_points


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
    total.counts = ledger.by_outcome()  # outcome words, as the scheduler reports them (not states)
    return total


def _rounds(campaign: Campaign, ledger: Ledger, run_round: Callable[[], Outcome], total: Outcome, signals: Any) -> None:
    while not signals.count:
        rows = ledger.rows()
        state = replay(campaign, rows)
        if state.result is not None:
            total.complete = True
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
    if total.interrupted and not total.complete:  # stopped after the round that finished the procedure?
        total.complete = replay(campaign, ledger.rows()).result is not None


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


def engine_oracle(campaign: Campaign, batch: int = 64) -> Oracle:
    """Outcomes of points of ``campaign`` simulated in this process by :func:`labrunner.engine.run_batch`
    (same configuration, seed and safety routine as the campaign's runs; no logs written)."""
    from labrunner import engine
    from labrunner.campaign.checks import StaticChecker
    from labrunner.rigs import registry

    def oracle(points: list[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
        configs = [campaign.expand(dict(p))[1] for p in points]
        checker = StaticChecker(campaign.rig_config)
        durations = {
            seq: d
            for (seq, _, _), d in (
                *(x for i, c in enumerate(configs) for x in checker.add(i, dict(points[i]), c)),
                *checker.flush(),
            )
        }
        groups: dict[float, list[int]] = {}  # runs of one lockstep batch share their length
        for i, duration in sorted(durations.items()):
            configs[i]["campaign"]["duration"] = duration
            groups.setdefault(duration, []).append(i)
        out: dict[int, Mapping[str, Any]] = {}
        with registry.load_rig(campaign.rig_ref, search=campaign.rig_search) as rig:
            for duration, members in groups.items():
                for lo in range(0, len(members), batch):
                    idx = members[lo : lo + batch]
                    results = engine.run_batch(
                        [configs[i] for i in idx],
                        rig,
                        fs=float(campaign.fs),
                        duration=duration,
                        seeds=[campaign.seed] * len(idx),
                        rig_safety=campaign.rig_safety,
                    )
                    out.update(
                        (
                            i,
                            {
                                "status": r.outcome.status,
                                "rms_error": r.metrics.get("rms_error"),
                                "input_energy": r.metrics.get("input_energy"),
                                "oscillating": r.metrics.get("oscillating"),
                            },
                        )
                        for i, r in zip(idx, results)
                    )
        return [out[i] for i in range(len(points))]

    return oracle
