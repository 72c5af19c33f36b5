"""The metrics table of a campaign directory: one row per grid point, from the ledger and the MCAPs.

The ledger gives each point's parameters, state, outcome and log path; each run's MCAP gives the
full metrics (:mod:`labrunner.metrics`). Logs are read in parallel worker processes.
The table doubles as a cache: a row whose log has the same size and modification time as when
it was computed is reused, so re-analysing a finished campaign reads no log at all.

Damaged material never stops the analysis: a torn log is salvaged and flagged, an unreadable or
missing one falls back to the ledger's metric summary and is listed in ``problems``, and files
moved to ``quarantine/`` are listed too.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner.metrics import BASE_METRICS, Roles, parse_windows, run_metrics
from labrunner.errors import LabrunnerError

#: Columns that identify a point and its run, in this order at the left of the table.
ID_COLUMNS = ("seq", "id", "state", "status", "monitor", "abort_time", "abort_value", "attempts", "log_path", "torn")
#: Columns that tell whether a cached row still matches its log file.
CACHE_COLUMNS = ("log_size", "log_mtime_ns")
#: Bump when the metrics change meaning: cached tables of another version are recomputed.
METRICS_VERSION = 2  # 2: windowed metrics and the oscillation detector
#: Parallel reading pays off above this many logs.
_PARALLEL_MIN = 64


@dataclass
class CampaignTable:
    """The metrics table and what went wrong while building it."""

    frame: pd.DataFrame
    problems: list[dict[str, str]] = field(default_factory=list)  # {"path", "kind", "detail"}
    n_read: int = 0  # logs read now (the rest came from the cache)


def roles_of(channels: Mapping[str, Mapping[str, Any]], units: Mapping[str, str] | None = None,
             limits: Mapping[str, tuple[float, float]] | None = None) -> Roles:
    """Metric roles from a log's ``channels`` record (signal → {"role", "unit"}); ``units`` (the
    rig's signal units) stands in where the log records no unit; ``limits`` (the rig's input
    limits) enable the oscillation detector."""
    by_role: dict[str, list[str]] = {}
    for name, info in channels.items():
        by_role.setdefault(str(info.get("role", "")), []).append(name)
    units = units or {}
    currents = tuple(n for n, info in channels.items() if (info.get("unit") or units.get(n)) == "A")
    error_hats = tuple(n for n in by_role.get("estimate", []) if n.startswith("e_hat_"))
    inputs = tuple(by_role.get("input", []))
    input_limits = tuple(limits[n] for n in inputs) if limits and all(n in limits for n in inputs) else ()
    return Roles(errors=tuple(by_role.get("error", [])), inputs=inputs,
                 error_hats=error_hats, currents=currents, input_limits=input_limits)


def log_metrics(path: str, units: Mapping[str, str] | None = None,
                limits: Mapping[str, tuple[float, float]] | None = None) -> dict[str, Any]:
    """Metrics, outcome and torn flag of one MCAP; ``{"error": ...}`` if it cannot be read.

    ``units``: the rig's signal units, for logs that record none; ``limits``: its input limits
    (see :func:`roles_of`).
    """
    from labrunner.logs import read_run

    try:
        log = read_run(path)
        frame = log.frame
        signals = {c: frame[c].to_numpy() for c in frame.columns}
        windows = parse_windows((log.metadata.get("config") or {}).get("metrics"))
        out: dict[str, Any] = run_metrics(signals, roles_of(log.channels, units, limits), fs=float(log.fs), windows=windows)
    except (LabrunnerError, OSError, ValueError, KeyError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    outcome = log.outcome or {}
    out.update(torn=bool(log.torn), log_status=outcome.get("status"), log_monitor=outcome.get("monitor"),
               log_time=outcome.get("time"), log_value=outcome.get("value"))
    return out


def _read_many(paths: Sequence[str], workers: int, units: Mapping[str, str] | None,
               limits: Mapping[str, tuple[float, float]] | None = None) -> list[dict[str, Any]]:
    read = functools.partial(log_metrics, units=dict(units or {}), limits=dict(limits or {}))
    if workers <= 1 or len(paths) < _PARALLEL_MIN:
        return [read(p) for p in paths]
    chunk = max(1, len(paths) // (workers * 8))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(read, paths, chunksize=chunk))


def _stat(path: Path) -> tuple[int, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


def _float(value: Any) -> float:
    return float(value) if value is not None else float("nan")


def ledger_frame(rows: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """One row per ledger point: ids, state, outcome details, parameters (dotted keys), ledger metrics."""
    records = []
    for r in rows:
        outcome = json.loads(r["outcome_json"]) if r["outcome_json"] else {}
        params = json.loads(r["parameters"])
        rec: dict[str, Any] = {
            "seq": int(r["seq"]), "id": r["id"], "state": r["state"],
            "status": r["outcome"] or r["state"],
            "monitor": outcome.get("monitor"),
            "abort_time": _float(outcome.get("time")) if r["outcome"] == "aborted" else np.nan,
            "abort_value": _float(outcome.get("value")) if r["outcome"] == "aborted" else np.nan,
            "attempts": int(r["attempts"]),
            "log_path": r["log_path"],
            "torn": False,
            **{k: v for k, v in params.items() if isinstance(v, (int, float, str, bool))},
            "rms_error": _float(r["rms_error"]), "input_energy": _float(r["input_energy"]),
            "max_abs_input": _float(r["max_abs_input"]),
        }
        records.append(rec)
    frame = pd.DataFrame.from_records(records)
    if frame.empty:
        frame = pd.DataFrame(columns=list(ID_COLUMNS))
    return frame


def _cached(cache: pd.DataFrame | None) -> dict[tuple[str, str], dict[str, Any]]:
    if cache is None or cache.empty or not set(CACHE_COLUMNS) <= set(cache.columns):
        return {}
    if "metrics_version" not in cache.columns or not (cache["metrics_version"] == METRICS_VERSION).all():
        return {}
    return {(r["id"], r["log_path"]): r for r in cache.to_dict("records")}


def build_table(
    rows: Sequence[Mapping[str, Any]],
    directory: Path,
    *,
    cache: pd.DataFrame | None = None,
    workers: int | None = None,
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> CampaignTable:
    """Merge ledger ``rows`` with metrics from their logs (reusing ``cache`` rows that still match);
    ``units`` are the rig's signal units, for logs that record none; ``limits`` its input limits
    (the oscillation detector's columns)."""
    frame = ledger_frame(rows)
    problems: list[dict[str, str]] = []
    cached = _cached(cache)
    todo: list[int] = []
    metrics: dict[int, dict[str, Any]] = {}
    stats: dict[int, tuple[int, int]] = {}
    for i, rec in enumerate(frame.to_dict("records")):
        if not isinstance(rec.get("log_path"), str):
            continue
        st = _stat(directory / rec["log_path"])
        if st is None:
            problems.append({"path": rec["log_path"], "kind": "missing", "detail": f"point {rec['id']}: log file not found"})
            continue
        stats[i] = st
        hit = cached.get((rec["id"], rec["log_path"]))
        if hit is not None and (hit["log_size"], hit["log_mtime_ns"]) == st:
            metrics[i] = {k: v for k, v in hit.items() if k not in frame.columns or k in (*BASE_METRICS, "torn")}
        else:
            todo.append(i)
    paths = [str(directory / frame.at[i, "log_path"]) for i in todo]
    for i, result in zip(todo, _read_many(paths, workers or os.cpu_count() or 1, units, limits)):
        if "error" in result:
            problems.append({"path": frame.at[i, "log_path"], "kind": "unreadable", "detail": result["error"]})
            continue
        metrics[i] = result
    for i, st in stats.items():
        if i in metrics:
            metrics[i]["log_size"], metrics[i]["log_mtime_ns"] = st
    extra = pd.DataFrame.from_dict(metrics, orient="index")
    if not extra.empty:
        extra = extra.drop(columns=[c for c in extra.columns if c.startswith("log_") and c not in CACHE_COLUMNS])
        extra = extra.reindex(frame.index)
        for col in extra.columns:  # the log's value where it was read, else the ledger's summary
            frame[col] = extra[col].combine_first(frame[col]) if col in frame.columns else extra[col]
        for col in CACHE_COLUMNS:
            frame[col] = frame[col].astype("Int64")
    frame["torn"] = frame["torn"].fillna(False).astype(bool)
    frame["metrics_version"] = METRICS_VERSION
    for rec in frame[frame["torn"]].to_dict("records"):
        problems.append({"path": rec["log_path"], "kind": "torn", "detail": f"point {rec['id']}: salvaged a torn log"})
    return CampaignTable(frame, problems, n_read=len(todo))


def quarantine_problems(quarantine_rows: Sequence[Mapping[str, Any]], directory: Path) -> list[dict[str, str]]:
    """Files moved to ``quarantine/``: those the ledger recorded, and any other file lying there."""
    out = [{"path": str(r["moved_to"]), "kind": "quarantined",
            "detail": f"point {r['point_id']}: {r['reason']} (was {r['original']}, {r['bytes']} bytes)"}
           for r in quarantine_rows]
    known = {Path(o["path"]).name for o in out}
    qdir = directory / "quarantine"
    if qdir.is_dir():
        for f in sorted(qdir.iterdir()):
            if f.is_file() and f.name not in known:
                out.append({"path": str(f.relative_to(directory)), "kind": "quarantined", "detail": "not in the ledger"})
    return out


def write_table(frame: pd.DataFrame, out: Path) -> tuple[Path, Path]:
    """Write ``metrics.csv`` and ``metrics.parquet`` into ``out`` (atomically, each)."""
    out.mkdir(parents=True, exist_ok=True)
    csv, parquet = out / "metrics.csv", out / "metrics.parquet"
    ordered = frame[[*[c for c in ID_COLUMNS if c in frame.columns], *[c for c in frame.columns if c not in ID_COLUMNS]]]
    tmp = csv.with_name(".metrics.csv.tmp")
    ordered.to_csv(tmp, index=False)
    tmp.replace(csv)
    tmp = parquet.with_name(".metrics.parquet.tmp")
    ordered.astype({c: "string" for c in ordered.columns if ordered[c].dtype == object}).to_parquet(tmp, index=False)
    tmp.replace(parquet)
    return csv, parquet


def read_cache(out: Path) -> pd.DataFrame | None:
    """The previous ``metrics.parquet`` in ``out``, or None (absent or unreadable: recompute)."""
    try:
        return pd.read_parquet(out / "metrics.parquet")
    except (OSError, ValueError, ImportError):
        return None
