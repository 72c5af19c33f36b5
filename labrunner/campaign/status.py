"""``labrunner status``: where a campaign stands, from its ledger and lock alone (reads only; safe
while it runs); while a runner runs, its rate and ETA are those it shows (from its lock record),
which count the runs in flight, not only the committed ones. Kept apart from
:mod:`labrunner.campaign.runner` so that the command loads no campaign validation, controllers or
numerics (start-up ≤ 0.2 s, issue 14)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from labrunner.campaign import integrity
from labrunner.campaign.ledger import Ledger, ledger_path
from labrunner.campaign.lock import holder
from labrunner.campaign.progress import OUTCOMES
from labrunner.campaign.rig_timing import timing_sql
from labrunner.rigs.device import lawflag

#: Up to this many points status runs every integrity check (:mod:`.integrity`, ≤ ~0.2 s); above,
#: only those that do not read every row, so that it answers in well under a second at 10^6 points
#: (analyse runs them all; resume too, unless the directory is sealed: :mod:`.seal`).
FULL_CHECK_POINTS = 20_000

#: The ledger ``meta`` key saying whether the campaign's rig is real ("1": its runs keep a
#: ``diagnostics`` record, a device loop's law check and the rig's timing) or a twin ("0": they keep
#: none, so status need not search every outcome for them: ~3 s at 10^6 points).
REAL_RIG = "real_rig"

#: A running runner's own rate and ETA (its lock record, renewed every second: :mod:`.progress`) are
#: shown while younger than this [s]; else the ledger's committed runs over the elapsed time.
FRESH_S = 30.0


def status(directory: str | Path) -> dict[str, Any]:
    """The ``labrunner status --json`` object (reads only)."""
    directory = Path(directory)
    with Ledger.open_readonly(directory, thorough=False) as ledger:
        meta = ledger.meta()
        if int(meta["points"]) <= FULL_CHECK_POINTS:  # the checks that read every row: ~10 µs a point
            integrity.verify(ledger.db, ledger_path(directory))
        outcomes = ledger.by_outcome()
        sessions = ledger.sessions()
        quarantined = len(ledger.quarantined())
        finished = ledger.db.execute("SELECT COUNT(*) FROM points WHERE finished_at IS NOT NULL").fetchone()[0]
        real = meta.get(REAL_RIG) != "0"  # a ledger written before the key was kept: searched
        timing = _timing(ledger) if real else None
        guided = _guided(meta, ledger) if "guided" in meta else None
        law = _law_check(ledger) if real else None
    running = holder(directory)
    now = time.time()
    elapsed = 0.0
    for i, s in enumerate(sessions):
        live = running is not None and i == len(sessions) - 1 and s["ended_at"] is None
        end = now if live else (s["ended_at"] or s["last_at"])
        elapsed += max(0.0, end - s["started_at"])
    total = sum(outcomes.values())
    remaining = outcomes.get("planned", 0) + outcomes.get("claimed", 0)
    rate = finished / elapsed if elapsed > 0 and finished else None
    estimate = round(remaining / rate, 1) if rate else (0.0 if remaining == 0 else None)
    shown = running.progress if running is not None else None
    if shown and now - float(shown.get("at", 0.0)) < FRESH_S:  # what the runner itself shows (runs in flight too)
        rate, estimate = shown.get("rate_per_s") or None, shown.get("estimate_s")
    return {
        "campaign": meta.get("campaign"),
        "directory": str(directory),
        "total": total,
        "outcomes": {word: outcomes.get(word, 0) for word in OUTCOMES},  # every command's words (progress.py)
        "quarantined": quarantined,
        "elapsed_s": round(elapsed, 3),
        "rate_per_s": round(rate, 3) if rate else None,
        "estimate_s": estimate,
        "running": None if running is None else {"host": running.host, "pid": running.pid},
        "sessions": len(sessions),
        **({"timing": timing} if timing else {}),
        **({"guided": guided} if guided is not None else {}),
        **({"law_check": law} if law is not None else {}),
    }


def law_check(directory: str | Path) -> dict[str, Any] | None:
    """Only the ``law_check`` entry of :func:`status` (None for a twin's campaign, which keeps none):
    what ``run`` and ``resume`` print at their end (they checked the ledger), without counting the
    campaign again."""
    with Ledger.open_readonly(Path(directory), verify=False) as ledger:
        return _law_check(ledger) if ledger.meta().get(REAL_RIG) != "0" else None


def _timing(ledger: Ledger) -> dict[str, int] | None:
    """A real rig's late ticks and overruns summed over its runs, and the runs that had any
    (None: no run carries them, e.g. a simulated campaign). One SQL pass, no JSON parsed here."""
    late, over = timing_sql("late_ticks"), timing_sql("overruns")
    row = ledger.db.execute(
        f"SELECT COUNT({over}), SUM({late}), SUM({over}), SUM({late} > 0), SUM({over} > 0) "
        "FROM points WHERE outcome_json IS NOT NULL"
    ).fetchone()
    if not row[0]:
        return None
    keys = ("runs", "late_ticks", "overruns", "runs_with_late_ticks", "runs_with_overruns")
    return {k: int(v or 0) for k, v in zip(keys, row)}


def _law_check(ledger: Ledger) -> dict[str, Any] | None:
    """The device-loop runs' reference-law check (:mod:`labrunner.rigs.device.lawflag`)."""
    return lawflag.summary(
        ledger.db.execute(
            "SELECT id, json_extract(outcome_json, '$.diagnostics.law_check.flag'), "
            "json_extract(outcome_json, '$.diagnostics.law_check.arithmetic') FROM points "
            "WHERE json_valid(outcome_json) AND json_extract(outcome_json, '$.diagnostics.law_check.flag') "
            "IS NOT NULL ORDER BY seq"
        )
    )


def _guided(meta: dict[str, str], ledger: Ledger) -> dict[str, Any]:
    """A guided campaign's decisions so far, replayed from the ledger. Only this loads the campaign
    (≈ 0.3 s): a grid campaign's status stays as light as before."""
    from labrunner.campaign.guided_run import stored_summary

    return stored_summary(meta, [dict(r) for r in ledger.rows()])
