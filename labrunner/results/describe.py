"""What a campaign or a run is, in a few lines: the text of ``repr()`` and the HTML a notebook
shows (``_repr_html_``). A campaign's facts come from its ledger (counts by outcome: one indexed
query, no table built), a run's from its log; neither raises: a fact that cannot be read is
left out, so that printing a result never fails."""

from __future__ import annotations

import html
import json
import math
import sqlite3
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from labrunner.errors import LabrunnerError

if TYPE_CHECKING:
    from labrunner.results.campaign import CampaignResults
    from labrunner.results.run import RunResults

Facts = list[tuple[str, str]]


def when(epoch: Any) -> str:
    """A Unix time as ``2026-12-04 15:20 UTC`` ("" if it is none)."""
    try:
        seconds = float(epoch)
    except (TypeError, ValueError):
        return ""
    if not math.isfinite(seconds):
        return ""
    return datetime.fromtimestamp(seconds, tz=UTC).strftime("%Y-%m-%d %H:%M UTC")


def _value(v: Any) -> str:
    return f"{v:.5g}" if isinstance(v, float) else str(v)


def logged_units(frame: Any) -> dict[str, str]:
    """Each signal's unit as the first readable log of the table (absolute ``log_path``) records it."""
    from labrunner.logs import read_metadata

    for path in frame["log_path"].dropna().head(5):
        try:
            channels = read_metadata(path).get("channels", {})
        except (LabrunnerError, OSError, ValueError):
            continue
        return {name: str(info.get("unit") or "") for name, info in channels.items() if isinstance(info, Mapping)}
    return {}


_HOUSE_UNITS = {"abort_time": "s", "log_size": "B", "log_mtime_ns": "ns"}


def column_units(frame: Any, known: Mapping[str, str], signals: Mapping[str, str]) -> dict[str, str]:
    """The unit of each column of a campaign's table that has one: ``known`` (the gains, the
    summary metrics, rig parameters: :func:`~labrunner.analysis.selection.table_units`), and
    a signal's RMS (``rms_<signal>``, an error's ``rms_e_<output>``) in the unit of the signal
    (``signals``); a window's (``<metric>@<window>``) and an aborted run's
    (``<metric>_until_abort``) as their metric's; the abort time and the log's size and mtime."""
    known = {**_HOUSE_UNITS, **known}
    out = {}
    for column in frame.columns:
        base = str(column).split("@", 1)[0].removesuffix("_until_abort")
        name = base.removeprefix("rms_") if base.startswith("rms_") else None
        found = [signals.get(n) for n in (name, *(name.removeprefix(p) for p in ("e_hat_", "e_")))] if name else []
        unit = known.get(base) or next((u for u in found if u), None)
        if unit:
            out[str(column)] = unit
    return out


def campaign_facts(campaign: CampaignResults) -> Facts:
    """(label, text) pairs: campaign, description, rig, created, points by outcome, parameters."""
    from labrunner.campaign.ledger import Ledger

    meta = campaign.meta
    facts = [("campaign", campaign.name)]
    counts = outcome_counts(campaign)
    try:
        with Ledger.open_readonly(campaign.directory, thorough=False) as ledger:
            first = ledger.db.execute("SELECT parameters FROM points ORDER BY seq LIMIT 1").fetchone()
    except (LabrunnerError, sqlite3.Error, OSError, ValueError):
        first = None
    description = _description(meta.get("campaign_file", ""))
    if description:
        facts.append(("description", description))
    if meta.get("rig"):
        facts.append(("rig", str(meta["rig"])))
    if when(meta.get("created_at")):
        facts.append(("created", when(meta.get("created_at"))))
    if counts:
        total = sum(counts.values())
        facts.append(("points", f"{total:,}: " + ", ".join(f"{n:,} {state}" for state, n in counts.items())))
    names = list(json.loads(first[0])) if first else []
    if names:
        facts.append(("parameters", ", ".join(names)))
    facts.append(("directory", str(campaign.directory)))
    return facts


def outcome_counts(campaign: CampaignResults) -> dict[str, int]:
    """Points by outcome (planned, claimed for those without one), most first; {} if unreadable."""
    from labrunner.campaign.ledger import Ledger

    query = "SELECT COALESCE(outcome, state), COUNT(*) FROM points GROUP BY 1 ORDER BY 2 DESC, 1"
    try:
        with Ledger.open_readonly(campaign.directory, thorough=False) as ledger:
            return {str(state): int(n) for state, n in ledger.db.execute(query)}
    except (LabrunnerError, sqlite3.Error, OSError, ValueError):
        return {}


def _description(campaign_file: str) -> str:
    """The ``[campaign] description`` of the campaign file's text kept in the ledger ("" if none)."""
    import tomllib

    try:
        value = tomllib.loads(campaign_file).get("campaign", {}).get("description", "")
    except (tomllib.TOMLDecodeError, AttributeError):
        return ""
    return value.strip().splitlines()[0] if isinstance(value, str) and value.strip() else ""


def run_facts(run: RunResults) -> Facts:
    """(label, text) pairs: point, outcome, samples and rate, start time, parameters, RMS error."""
    facts = [("point", run.id)]
    try:
        outcome, fs, record = run.outcome, run.fs, run.metadata.get("run") or {}
        parameters, metrics = run.parameters, run.metrics
    except (LabrunnerError, OSError, ValueError, KeyError):  # a repr never raises: what the log says is left out
        return [*facts, ("log", str(run.path))]
    status = outcome.get("status") or "torn (the run never finished)"
    if outcome.get("monitor"):
        status += f" ({outcome['monitor']} at t = {_value(outcome.get('time'))} s)"
    facts.append(("outcome", status))
    n = outcome.get("n_samples") or 0
    facts.append(("samples", f"{n:,} at {fs:g} Hz ({n / fs:g} s)" if fs else f"{n:,}"))
    if when(record.get("start_time")):
        facts.append(("started", when(record.get("start_time"))))
    if parameters:
        facts.append(("parameters", ", ".join(f"{k} = {_value(v)}" for k, v in parameters.items())))
    if isinstance(metrics.get("rms_error"), (int, float)):
        until = " (until the abort)" if outcome.get("status") == "aborted" else ""
        facts.append(("rms_error", _value(metrics["rms_error"]) + until))
    facts.append(("log", str(run.path)))
    return facts


def text(kind: str, facts: Sequence[tuple[str, str]]) -> str:
    """``Kind: label value`` lines, aligned."""
    width = max((len(label) for label, _ in facts), default=0)
    return "\n".join([f"{kind}:", *(f"  {label:<{width}}  {value}" for label, value in facts)])


def html_table(kind: str, facts: Sequence[tuple[str, str]]) -> str:
    """The facts as a small HTML table (every value escaped)."""
    rows = "".join(
        f"<tr><th style='text-align:left'>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in facts
    )
    return f"<table><caption style='text-align:left'><b>{html.escape(kind)}</b></caption>{rows}</table>"
