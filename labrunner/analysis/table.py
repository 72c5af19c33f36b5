"""The metrics table of a campaign directory: one row per grid point, from the ledger.

The ledger gives each point's parameters, outcome, log path and — committed with the run — every
metric of its run (:mod:`labrunner.metrics`), so building the table reads no log. Logs are read
(in parallel worker processes) only for rows whose ledger holds no metrics (a ledger from before
they were committed) or when asked to recompute; such rows are cached in ``metrics.parquet``
and reused while their log keeps its size and modification time.

Columns a user ranks by describe whole runs only: an aborted run's metrics cover the run up to
its abort, so they are moved to ``<metric>_until_abort`` columns (``rms_error_until_abort``) and
its ``rms_error`` etc. stay empty. ``outcome`` is one word per point: completed, no-motion,
aborted, failed, or the ledger's planned / claimed for points without a run. In the written
files ``log_path`` is relative to the file that holds it (``../runs/<id>.mcap`` from
``report/metrics.csv``); counts are integers.

Damaged material never stops the analysis: a torn log is salvaged and flagged, an unreadable or
missing one falls back to the ledger's metrics and is listed in ``problems``, and files moved to
``quarantine/`` are listed too.
"""

from __future__ import annotations

import functools
import itertools
import json
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner import run_identity
from labrunner.campaign.rig_timing import timing_counts
from labrunner.errors import LabrunnerError
from labrunner.metrics import BASE_METRICS, Roles, parse_windows, run_metrics
from labrunner.rigs.device.lawflag import flag_of

#: Columns that identify a point and its run, in this order at the left of the table.
ID_COLUMNS = (
    "seq",
    "id",
    "outcome",
    "monitor",
    "abort_time",
    "abort_value",
    "attempts",
    "log_path",
    "torn",
    "log_state",
    "law_check",
)
#: Suffix of the columns that hold an aborted run's metrics (over the run up to its abort).
UNTIL_ABORT = "_until_abort"
#: Columns that tell whether a cached row still matches its log file.
CACHE_COLUMNS = ("log_size", "log_mtime_ns")
#: A real rig's timing counts per run (:mod:`labrunner.campaign.rig_timing`; absent for a twin).
TIMING_COLUMNS = ("late_ticks", "overruns")
#: Integer columns (nullable where a point has no run).
INTEGER_COLUMNS = ("seq", "attempts", "n_samples", *CACHE_COLUMNS, *TIMING_COLUMNS)
#: Bump when the metrics change meaning: cached tables of another version are recomputed.
METRICS_VERSION = (
    5  # 2: windowed metrics and the oscillation detector; 3: its thresholds; 4: aborted runs' in _until_abort
    # columns; 5: the detector's sustained-oscillation rule (periodicity)
)
#: Parallel reading pays off above this many logs.
_PARALLEL_MIN = 64
_LEDGER_METRICS = ("rms_error", "input_energy", "max_abs_input")  # the ledger's own columns (older ledgers: only these)


@dataclass
class CampaignTable:
    """The metrics table and what went wrong while building it."""

    frame: pd.DataFrame
    problems: list[dict[str, str]] = field(default_factory=list)  # {"path", "kind", "detail"}
    n_read: int = 0  # logs read now (the rest came from the ledger or the cache)


def roles_of(
    channels: Mapping[str, Mapping[str, Any]],
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
) -> Roles:
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
    return Roles(
        errors=tuple(by_role.get("error", [])),
        inputs=inputs,
        error_hats=error_hats,
        currents=currents,
        input_limits=input_limits,
    )


def log_metrics(
    path: str, units: Mapping[str, str] | None = None, limits: Mapping[str, tuple[float, float]] | None = None
) -> dict[str, Any]:
    """Metrics and torn flag of one MCAP; ``{"error": ...}`` if it cannot be read.

    ``units``: the rig's signal units, for logs that record none; ``limits``: its input limits
    (see :func:`roles_of`).
    """
    from labrunner.logs import read_run

    try:
        log = read_run(path)
        named = run_identity.named_point(log.metadata)
        frame = log.frame
        signals = {c: frame[c].to_numpy() for c in frame.columns}
        windows = parse_windows((log.metadata.get("config") or {}).get("metrics"))
        out: dict[str, Any] = run_metrics(
            signals, roles_of(log.channels, units, limits), fs=float(log.fs), windows=windows
        )
    except (LabrunnerError, OSError, ValueError, KeyError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    out["torn"] = bool(log.torn)
    out["log_point"] = named
    return out


def _named_point(path: str) -> dict[str, Any]:
    """``{"log_point": id}`` the log names (its metadata alone), or ``{"error": ...}``."""
    try:
        return {"log_point": run_identity.read_named_point(path)}
    except (LabrunnerError, OSError, ValueError, KeyError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}


def _read_many(
    read: Callable[[str], dict[str, Any]],
    paths: Sequence[str],
    workers: int,
    tick: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    """``read(path)`` of every path, in a process pool when there are many."""
    out: list[dict[str, Any]] = []
    if workers <= 1 or len(paths) < _PARALLEL_MIN:
        for p in paths:
            out.append(read(p))
            if tick:
                tick(1)
        return out
    chunk = max(1, min(64, len(paths) // (workers * 8)))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for result in pool.map(read, paths, chunksize=chunk):
            out.append(result)
            if tick:
                tick(1)
    return out


_MAGIC = b"\x89MCAP0\r\n"


def _stat(path: Path) -> tuple[int, int, bool] | None:
    """(size, mtime [ns], intact) of a log, None if it is missing; intact: it begins and ends with
    the MCAP magic (a writer killed mid-file leaves no closing magic), ~10 µs instead of a read."""
    try:
        with open(path, "rb") as f:
            st = os.fstat(f.fileno())
            head = f.read(len(_MAGIC))
            intact = st.st_size >= 2 * len(_MAGIC) and head == _MAGIC
            if intact:
                f.seek(-len(_MAGIC), os.SEEK_END)
                intact = f.read(len(_MAGIC)) == _MAGIC
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns, intact


def _float(value: Any) -> float:
    return float(value) if value is not None else float("nan")


def _ledger_metrics(r: Mapping[str, Any]) -> dict[str, Any] | None:
    """The run's metrics as committed (None: this ledger row holds only the three summary columns)."""
    text = r.get("metrics_json")
    if text:  # an undefined metric is stored as null (strict JSON; older ledgers: NaN)
        return {k: np.nan if v is None else v for k, v in json.loads(text).items()}
    return None


#: Ledger rows turned into table rows at a time: the Python objects of one chunk are freed before
#: the next is read, so that building the table of 10^6 points holds one chunk's, not all.
CHUNK_ROWS = 20_000


def ledger_frame(rows: Iterable[Mapping[str, Any]]) -> tuple[pd.DataFrame, list[int]]:
    """One row per ledger point: ids, outcome and its details, parameters (dotted keys), metrics;
    and the positions of finished rows whose ledger holds no full metrics (their logs must be
    read). ``rows`` may be an iterator (a ledger cursor): it is consumed :data:`CHUNK_ROWS` at a
    time."""
    frames: list[pd.DataFrame] = []
    missing: list[int] = []
    iterator = iter(rows)
    start = 0
    while chunk := list(itertools.islice(iterator, CHUNK_ROWS)):
        frame, absent = _chunk_frame(chunk)
        frames.append(frame.set_axis(range(start, start + len(frame))))
        missing += [start + i for i in absent]
        start += len(chunk)
    if not frames:
        return pd.DataFrame(columns=list(ID_COLUMNS)), missing
    return (frames[0] if len(frames) == 1 else pd.concat(frames)), missing


def _chunk_frame(rows: Sequence[Mapping[str, Any]]) -> tuple[pd.DataFrame, list[int]]:
    """:func:`ledger_frame` of one chunk of rows (positions relative to it)."""
    records = []
    missing: list[int] = []
    for i, r in enumerate(rows):
        outcome = json.loads(r["outcome_json"]) if r["outcome_json"] else {}
        params = json.loads(r["parameters"])
        aborted = r["outcome"] == "aborted"
        metrics = _ledger_metrics(r)
        if metrics is None:
            metrics = {k: _float(r.get(k)) for k in _LEDGER_METRICS}
            if r.get("log_path"):
                missing.append(i)
        records.append(
            {
                "seq": r["seq"],
                "id": r["id"],
                "outcome": r["outcome"] or r["state"],
                "monitor": outcome.get("monitor"),
                "abort_time": _float(outcome.get("time")) if aborted else np.nan,
                "abort_value": _float(outcome.get("value")) if aborted else np.nan,
                "attempts": r["attempts"],
                "log_path": r["log_path"],
                "torn": False,
                "law_check": flag_of(outcome),  # a device-loop run's reference-law check, "" for others
                **{k: v for k, v in params.items() if isinstance(v, (int, float, str, bool))},
                **metrics,
                **timing_counts(outcome.get("diagnostics")),
            }
        )
    return pd.DataFrame.from_records(records), missing


def metric_columns(frame: pd.DataFrame) -> list[str]:
    """The columns holding a run's metrics, of the whole run or of a window (``<metric>@<name>``),
    other than its sample counts."""
    prefixes = ("rms_", "energy_", "max_")

    def base(column: str) -> str:
        return column.split("@", 1)[0]

    return [
        c
        for c in frame.columns
        if (base(c) in BASE_METRICS or base(c).startswith(prefixes))
        and base(c) != "n_samples"
        and not c.endswith(UNTIL_ABORT)
    ]


def split_aborted(frame: pd.DataFrame) -> pd.DataFrame:
    """Move the metrics of aborted runs to ``<metric>_until_abort`` columns (see the module)."""
    aborted = (frame["outcome"] == "aborted").to_numpy()
    out = {}
    for col in metric_columns(frame):
        values = frame[col].to_numpy(dtype=float)
        out[col] = np.where(aborted, np.nan, values)
        out[col + UNTIL_ABORT] = np.where(aborted, values, np.nan)
    return frame.assign(**out)


def _cached(cache: pd.DataFrame | None) -> dict[str, dict[str, Any]]:
    if cache is None or cache.empty or not set(CACHE_COLUMNS) <= set(cache.columns):
        return {}
    if "metrics_version" not in cache.columns or not (cache["metrics_version"] == METRICS_VERSION).all():
        return {}
    return {r["id"]: r for r in cache.to_dict("records")}


def _proved(hit: Mapping[str, Any] | None, stat: tuple[int, int]) -> bool:
    """Whether a cached row says its log, this same file (size, mtime), was proved to be its own."""
    if hit is None or hit.get("log_state") != LOG_OK:
        return False
    size, mtime = hit.get("log_size"), hit.get("log_mtime_ns")
    return bool(pd.notna(size) and pd.notna(mtime)) and (int(size), int(mtime)) == stat


def _unsplit(row: Mapping[str, Any], known: Sequence[str]) -> dict[str, Any]:
    """A cached table row's metrics as :func:`log_metrics` gave them (aborted runs' back from
    their ``_until_abort`` columns); columns the ledger fills (``known``) left out."""
    out = {}
    for key, value in row.items():
        if key.endswith(UNTIL_ABORT) or (key in known and key not in (*BASE_METRICS, "torn")):
            continue
        until = row.get(key + UNTIL_ABORT)
        out[key] = until if until is not None and pd.notna(until) else value
    return out


def build_table(
    rows: Iterable[Mapping[str, Any]],
    directory: Path,
    *,
    cache: pd.DataFrame | None = None,
    workers: int | None = None,
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
    recompute: bool = False,
    tick: Callable[[int], None] | None = None,
    announce: Callable[[int], None] | None = None,
) -> CampaignTable:
    """The table of ledger ``rows``: metrics from the ledger; from the logs (reusing ``cache`` rows
    that still match) where the ledger has none, or for every run with ``recompute``. ``units``
    are the rig's signal units, for logs that record none; ``limits`` its input limits (the
    oscillation detector's columns); ``announce(n)`` is told how many logs will be read (before
    the first), ``tick(n)`` as they are read."""
    frame, missing_list = ledger_frame(rows)
    missing = set(missing_list)
    problems: list[dict[str, str]] = []
    paths = frame["log_path"].tolist()
    todo = set(i for i, p in enumerate(paths) if isinstance(p, str)) if recompute else set(missing)
    stats: dict[int, tuple[int, int]] = {}  # (size, mtime) of the logs to read or to check against the cache
    for i, rel in enumerate(paths):  # every log the table names must exist, whole
        if not isinstance(rel, str):
            continue
        st = _stat(directory / rel)
        if st is None:
            problems.append(
                {"path": rel, "kind": "missing", "detail": f"point {frame.at[i, 'id']}: log file not found"}
            )
            continue
        stats[i] = st[:2]  # every log is checked against its row: by its metadata unless proved before
        if not st[2]:
            todo.add(i)  # damaged: read it (salvage) to flag it, its metrics stay the ledger's
    todo = sorted(i for i in todo if i in stats)
    cached = {} if recompute else _cached(cache)
    metrics: dict[int, dict[str, Any]] = {}
    read: list[int] = []
    for i in todo:
        hit = cached.get(frame.at[i, "id"])
        if hit is not None and (hit["log_size"], hit["log_mtime_ns"]) == stats[i]:
            metrics[i] = _unsplit(hit, frame.columns)
        else:
            read.append(i)
    if announce and read:
        announce(len(read))
    workers = workers or os.cpu_count() or 1
    metrics_of = functools.partial(log_metrics, units=dict(units or {}), limits=dict(limits or {}))
    results = _read_many(metrics_of, [str(directory / paths[i]) for i in read], workers, tick)
    # every log proves which point it is: those read now by their metadata; the others by their
    # run record, unless the cache saw this very file (size, mtime) back its row before
    unread = [i for i in sorted(set(stats) - set(read)) if not _proved(cached.get(frame.at[i, "id"]), stats[i])]
    named = _read_many(_named_point, [str(directory / paths[i]) for i in unread], workers)
    foreign: set[int] = set()
    for i, result in [*zip(read, results), *zip(unread, named)]:
        if "error" in result:
            problems.append({"path": paths[i], "kind": "unreadable", "detail": result["error"]})
            continue
        problem = run_identity.describe(result.pop("log_point"), frame.at[i, "id"])
        if problem:
            problems.append({"path": paths[i], "kind": FOREIGN, "detail": problem})
            foreign.add(i)
    for i, result in zip(read, results):
        if "error" in result or i in foreign:  # a foreign log's metrics are another point's
            continue
        if i not in missing and not recompute:  # a damaged log the ledger has whole metrics of: flag it only
            result = {"torn": result["torn"]}
        metrics[i] = result
    for i in stats:  # which file backed each row: the next analysis trusts a file it proved
        metrics.setdefault(i, {})["log_size"], metrics[i]["log_mtime_ns"] = stats[i]
    if metrics:
        extra = pd.DataFrame.from_dict(metrics, orient="index").reindex(frame.index)
        extra = extra.drop(columns=[c for c in ("metrics_version", *ID_COLUMNS) if c in extra.columns and c != "torn"])
        for col in extra.columns:  # the log's value where it was read, else the ledger's
            frame[col] = extra[col].combine_first(frame[col]) if col in frame.columns else extra[col]
    frame["torn"] = frame["torn"].fillna(False).astype(bool)
    frame = split_aborted(frame)
    for col in [*INTEGER_COLUMNS, *(c for c in frame.columns if c.startswith("n_samples@"))]:
        if col in frame.columns:
            frame[col] = pd.to_numeric(frame[col]).round().astype("Int64")
    frame["metrics_version"] = METRICS_VERSION
    for rec in frame.loc[frame["torn"], ["id", "log_path"]].to_dict("records"):
        problems.append({"path": rec["log_path"], "kind": "torn", "detail": f"point {rec['id']}: salvaged a torn log"})
    frame["log_state"] = log_states(frame["log_path"], problems)
    return CampaignTable(frame, problems, n_read=len(read))


#: ``log_state`` of a row whose log is fine; the others are the problems' kinds.
LOG_OK = "ok"
#: ``log_state`` of a row whose log names another point (swapped or copied on disk).
FOREIGN = "foreign"


def log_states(log_paths: pd.Series, problems: Sequence[Mapping[str, str]]) -> pd.Series:
    """Per row: "ok", or what is wrong with its log ("missing", "unreadable", "torn", "foreign":
    another point's run), or empty
    where the point has none (a failed run, an unfinished point) — so that the table alone says
    which metrics a log no longer backs."""
    kinds = {p["path"]: p["kind"] for p in problems if p["kind"] in ("missing", "unreadable", "torn", FOREIGN)}
    return log_paths.map(lambda rel: kinds.get(rel, LOG_OK) if isinstance(rel, str) else None)


def quarantine_problems(quarantine_rows: Sequence[Mapping[str, Any]], directory: Path) -> list[dict[str, str]]:
    """Files moved to ``quarantine/``: those the ledger recorded, and any other file lying there."""
    out = [
        {
            "path": str(r["moved_to"]),
            "kind": "quarantined",
            "detail": ("" if r["point_id"] is None else f"point {r['point_id']}: ")
            + f"{r['reason']} (was {r['original']}, {r['bytes']} bytes)",
        }
        for r in quarantine_rows
    ]
    known = {Path(o["path"]).name for o in out}
    qdir = directory / "quarantine"
    if qdir.is_dir():
        for f in sorted(qdir.iterdir()):
            if f.is_file() and f.name not in known:
                out.append(
                    {"path": str(f.relative_to(directory)), "kind": "quarantined", "detail": "not in the ledger"}
                )
    return out


def relative_paths(paths: pd.Series, directory: Path, out: Path) -> pd.Series:
    """Campaign-relative paths as seen from the folder ``out`` (None stays None)."""
    base = os.path.relpath(directory.resolve(), out.resolve())
    return paths.map(lambda p: os.path.join(base, p) if isinstance(p, str) else p)


def ordered(frame: pd.DataFrame) -> pd.DataFrame:
    """The table's columns in their order: ids, parameters, metrics, then the rest."""
    return frame[[*[c for c in ID_COLUMNS if c in frame.columns], *[c for c in frame.columns if c not in ID_COLUMNS]]]


def write_table(frame: pd.DataFrame, out: Path, directory: Path) -> tuple[Path, Path]:
    """Write ``metrics.csv`` and ``metrics.parquet`` into ``out`` (atomically, each), log paths
    relative to ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    csv, parquet = out / "metrics.csv", out / "metrics.parquet"
    table = ordered(frame.assign(log_path=relative_paths(frame["log_path"], directory, out)))
    tmp = csv.with_name(".metrics.csv.tmp")
    table.to_csv(tmp, index=False)
    tmp.replace(csv)
    tmp = parquet.with_name(".metrics.parquet.tmp")
    table.astype({c: "string" for c in table.columns if table[c].dtype == object}).to_parquet(tmp, index=False)
    tmp.replace(parquet)
    return csv, parquet


def read_cache(out: Path) -> pd.DataFrame | None:
    """The previous ``metrics.parquet`` in ``out``, or None (absent or unreadable: recompute)."""
    try:
        return pd.read_parquet(out / "metrics.parquet")
    except (OSError, ValueError, ImportError):
        return None
