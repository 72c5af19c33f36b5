"""The metrics table of a campaign directory: one row per grid point, from the ledger.

The ledger gives each point's parameters, outcome, log path and — committed with the run — every
metric of its run (:mod:`labrunner.metrics`), so building the table reads no log. Logs are read
(in parallel worker processes) only for rows whose ledger holds no metrics (a ledger from before
they were committed) or when asked to recompute; such rows are cached in ``metrics.parquet``
and reused while their log keeps its size and modification time.

Columns a user ranks by describe whole runs only: an aborted run's metrics cover the run up to
its abort (a failed one's up to its failure), so they are moved to ``<metric>_until_abort`` columns
(``rms_error_until_abort``, the name :func:`labrunner.metrics.as_reported` gives them everywhere)
and its ``rms_error`` etc. stay empty. ``outcome`` is one word per point: completed, no-motion,
aborted, failed, or the ledger's planned / claimed for points without a run. In the written
files ``log_path`` is relative to the file that holds it (``../runs/<id>.mcap`` from
``report/metrics.csv``); counts are integers.

Damaged material never stops the analysis: a torn log is salvaged and flagged, an unreadable or
missing one falls back to the ledger's metrics and is listed in ``problems``, and files moved to
``quarantine/`` are listed too.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pandas.api.types import union_categoricals

from labrunner import run_identity
from labrunner.analysis.log_checks import (
    CACHE_COLUMNS,
    LogChecks,
    cached_rows,
    disagrees,
    identity,
    named_point,
    proved_by_cache,
    read_many,
    same_file,
)
from labrunner.analysis.table_rows import Chunk, chunk_columns
from labrunner.errors import LabrunnerError
from labrunner.metrics import (
    BASE_METRICS,
    CUT_SHORT,
    UNTIL_ABORT,
    Roles,
    closes_loop,
    parse_windows,
    ranked,
    run_metrics,
)

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
    "law_arithmetic",
)
#: A real rig's timing counts per run (:mod:`labrunner.campaign.rig_timing`; absent for a twin).
TIMING_COLUMNS = ("late_ticks", "overruns")
#: Integer columns (nullable where a point has no run).
INTEGER_COLUMNS = ("seq", "attempts", "n_samples", *CACHE_COLUMNS, *TIMING_COLUMNS)
#: Bump when the metrics change meaning: cached tables of another version are recomputed.
METRICS_VERSION = (
    7  # 2: windowed metrics and the oscillation detector; 3: its thresholds; 4: aborted runs' in _until_abort
    # columns; 5: the detector's sustained-oscillation rule (periodicity); 6: failed runs' in _until_abort too;
    # 7: detector version 2 (short-run limit cycles, ring-downs, undecided, detector_version)
)


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
        frame = log.frame
        signals = {c: frame[c].to_numpy() for c in frame.columns}
        config = log.metadata.get("config") or {}
        windows = parse_windows(config.get("metrics"))
        limits = limits if closes_loop(config) else None  # an open-loop run: no detector (labrunner.metrics)
        out: dict[str, Any] = run_metrics(
            signals, roles_of(log.channels, units, limits), fs=float(log.fs), windows=windows
        )
    except (LabrunnerError, OSError, ValueError, KeyError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    out["torn"] = bool(log.torn)
    out.update(identity(log))
    return out


#: Text columns kept as such; every other text column (outcome, monitor, law_check, text
#: parameters: a few words repeated) is categorical, 1 byte a row instead of ~16.
FREE_TEXT = ("id", "log_path")


def ledger_frame(
    chunks: Iterable[Chunk],
    on_chunk: Callable[[int, Chunk, list[int]], None] | None = None,
) -> tuple[pd.DataFrame, list[int]]:
    """One row per ledger point: ids, outcome and its details, parameters (dotted keys), metrics;
    and the positions of finished rows whose ledger holds no full metrics (their logs must be
    read). ``chunks`` (:func:`ledger_chunks`, :func:`in_chunks`) are consumed one at a time, each
    handed to ``on_chunk(start, chunk, positions without metrics)`` and turned into columns,
    which are joined column by column (so the table is never held twice)."""
    pieces: dict[str, list[pd.Series]] = {}
    lengths: list[int] = []
    missing: list[int] = []
    start = fresh = 0
    for chunk in chunks:
        columns, absent = chunk_columns(chunk)
        if on_chunk is not None:
            on_chunk(start, chunk, absent)
        n = len(chunk["seq"])
        for col, values in columns.items():
            pieces.setdefault(col, [None] * len(lengths)).append(pd.Series(values, name=col))
        lengths.append(n)
        for column in pieces.values():
            column += [None] * (len(lengths) - len(column))  # a column this chunk lacks
        fresh += 1
        if fresh == _MERGE:  # join the last chunks' small pieces (see _MERGE)
            for column in pieces.values():
                column[-fresh:] = [_joined(_filled(column[-fresh:], lengths[-fresh:]))]
            lengths[-fresh:] = [sum(lengths[-fresh:])]
            fresh = 0
        missing += [start + i for i in absent]
        start += n
        del columns, chunk
    if not lengths:
        return pd.DataFrame(columns=list(ID_COLUMNS)), missing
    columns = {}
    for col in list(pieces):
        columns[col] = _joined(_filled(pieces.pop(col), lengths))
    return pd.DataFrame(columns, copy=False), missing


#: Chunks whose pieces of a column are joined as soon as they are all there: a piece of one chunk
#: (80 kB of floats) lies in the C heap, where the many freed ones would stay as the process's
#: memory; pieces of 16 chunks are large enough to be mapped and unmapped on their own.
_MERGE = 32


def _filled(pieces: list[pd.Series | None], lengths: list[int]) -> list[pd.Series]:
    """The pieces of a column, NaN for the chunks that lack it."""
    return [p if p is not None else pd.Series(np.full(n, np.nan)) for p, n in zip(pieces, lengths)]


def _is_text(piece: pd.Series) -> bool:
    return (
        pd.api.types.is_string_dtype(piece.dtype)
        or isinstance(piece.dtype, pd.CategoricalDtype)
        or bool(piece.isna().all())
    )


def _joined(pieces: list[pd.Series]) -> pd.Series:
    """One column from its chunks' pieces: text as categories (see :data:`FREE_TEXT`) or
    strings, the rest as ``pd.concat`` types it."""
    name = next((p.name for p in pieces if p.name is not None), None)
    if all(_is_text(p) for p in pieces) and not all(p.isna().all() for p in pieces):
        if name in FREE_TEXT:
            return _one_chunk(pd.concat([p.astype("str") for p in pieces], ignore_index=True).rename(name))
        parts = [
            p.array if isinstance(p.dtype, pd.CategoricalDtype) else pd.Categorical(p.astype("str")) for p in pieces
        ]
        return pd.Series(union_categoricals(parts, sort_categories=True), name=name)
    return pd.concat(pieces, ignore_index=True).rename(name)


def _one_chunk(text: pd.Series) -> pd.Series:
    """An Arrow-backed text column in one piece: joined from its chunks' pieces it is a chunked
    array, which Arrow joins again, whole, for every row taken from it (a run plotted, a row of
    the report: +34 MB for each take of 10^6 log paths)."""
    import pyarrow as pa

    data = text.array.__arrow_array__() if hasattr(text.array, "__arrow_array__") else None
    if not isinstance(data, pa.ChunkedArray) or data.num_chunks <= 1:
        return text
    return pd.Series(pd.array(data.combine_chunks(), dtype=text.dtype), name=text.name)


def metric_columns(frame: pd.DataFrame) -> list[str]:
    """The columns holding a run's metrics, of the whole run or of a window (``<metric>@<name>``),
    other than its sample counts (:func:`labrunner.metrics.ranked`)."""
    return [c for c in frame.columns if ranked(c) and not c.endswith(UNTIL_ABORT)]


def split_aborted(frame: pd.DataFrame) -> None:
    """Move the metrics of runs cut short (aborted or failed) to ``<metric>_until_abort`` columns
    (see the module), in place: a column at a time, never a second copy of the table's metrics."""
    aborted = frame["outcome"].isin(CUT_SHORT).to_numpy(dtype=bool)
    for col in metric_columns(frame):
        values = frame[col].to_numpy(dtype=float)
        frame[col + UNTIL_ABORT] = np.where(aborted, values, np.nan)
        frame[col] = np.where(aborted, np.nan, values)
        del values


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
    chunks: Iterable[Chunk],
    directory: Path,
    *,
    cache: Path | None = None,
    workers: int | None = None,
    units: Mapping[str, str] | None = None,
    limits: Mapping[str, tuple[float, float]] | None = None,
    recompute: bool = False,
    tick: Callable[[int], None] | None = None,
    announce: Callable[[int], None] | None = None,
) -> CampaignTable:
    """The table of the ledger rows in ``chunks`` (:func:`ledger_chunks`): metrics from the ledger; from the logs (reusing the rows of
    the previous table at ``cache``, its ``metrics.parquet``, that still match) where the ledger
    has none, or for every run with ``recompute``. Every log is checked (:mod:`.log_checks`).
    ``units`` are the rig's signal units, for logs that record none; ``limits`` its input limits
    (the oscillation detector's columns); ``announce(n)`` is told how many logs will be read
    (before the first), ``tick(n)`` as they are read."""
    checks = LogChecks(directory, recompute)
    frame, _ = ledger_frame(chunks, checks.add)
    sizes, mtimes = checks.stats()
    ids, paths = frame["id"], frame["log_path"]
    wanted = [] if recompute else [*checks.todo, *checks.unproved]
    cached = cached_rows(cache, set(ids.iloc[wanted]), METRICS_VERSION)
    metrics: dict[int, dict[str, Any]] = {}
    read: list[int] = []
    unproved = list(checks.unproved)
    for i in checks.todo:
        hit = cached.get(ids.iat[i])
        if same_file(hit, (sizes[i], mtimes[i])):
            metrics[i] = _unsplit(hit, frame.columns)
            if i not in checks.fingerprinted:
                unproved.append(i)
        else:
            read.append(i)
    if announce and read:
        announce(len(read))
    workers = workers or os.cpu_count() or 1
    metrics_of = functools.partial(log_metrics, units=dict(units or {}), limits=dict(limits or {}))
    results = list(read_many(metrics_of, [str(directory / paths.iat[i]) for i in read], workers, tick))
    # every log proves which point it is: those read now by their metadata; the others by the
    # fingerprint the ledger recorded, else by the cache having seen this very file back its row
    stat = {i: (int(sizes[i]), int(mtimes[i])) for i in unproved}
    unread = sorted(i for i in unproved if not proved_by_cache(cached.get(ids.iat[i]), stat[i], LOG_OK))
    named = read_many(named_point, [str(directory / paths.iat[i]) for i in unread], workers)
    problems = checks.problems
    foreign: set[int] = set()  # … and damaged: their metrics are another point's, or not all there
    for i, result in [*zip(read, results), *zip(unread, named)]:
        if "error" in result:
            problems.append({"path": paths.iat[i], "kind": "unreadable", "detail": result["error"]})
            continue
        problem = run_identity.describe(result.pop("log_point"), ids.iat[i])
        damaged = result.pop("log_damaged", "")
        differs = disagrees(result, checks.expected.get(i))
        for key in ("log_metadata", "log_status"):
            result.pop(key, None)
        if problem:
            problems.append({"path": paths.iat[i], "kind": FOREIGN, "detail": problem})
            foreign.add(i)
        elif damaged:
            problems.append({"path": paths.iat[i], "kind": DAMAGED, "detail": f"point {ids.iat[i]}: {damaged}"})
            foreign.add(i)
        elif differs:
            problems.append({"path": paths.iat[i], "kind": DISAGREES, "detail": f"point {ids.iat[i]}: {differs}"})
    for i, result in zip(read, results):
        if "error" in result or i in foreign:  # a foreign log's metrics are another point's
            continue
        if i not in checks.no_metrics and not recompute:  # a damaged log the ledger has whole metrics of: flag it only
            result = {"torn": result["torn"]}
        metrics[i] = result
    if metrics:
        extra = pd.DataFrame.from_dict(metrics, orient="index")
        drop = ("metrics_version", *CACHE_COLUMNS, *(c for c in ID_COLUMNS if c != "torn"))
        for col in extra.columns.drop([c for c in drop if c in extra.columns]):
            frame[col] = _overlaid(frame[col] if col in frame.columns else None, extra[col], len(frame))
    frame["torn"] = frame["torn"].fillna(False).astype(bool)
    split_aborted(frame)
    for col in [*INTEGER_COLUMNS, *(c for c in frame.columns if c.startswith("n_samples@"))]:
        if col in frame.columns and col not in CACHE_COLUMNS:
            frame[col] = pd.to_numeric(frame[col]).round().astype("Int64")
    for col, values in zip(CACHE_COLUMNS, (sizes, mtimes)):  # which file backed each row: the next analysis's cache
        frame[col] = pd.arrays.IntegerArray(values, values < 0)
    for rec in frame.loc[frame["torn"], ["id", "log_path"]].to_dict("records"):
        problems.append({"path": rec["log_path"], "kind": "torn", "detail": f"point {rec['id']}: salvaged a torn log"})
    frame["log_state"] = log_states(frame["log_path"], problems)
    return CampaignTable(frame, problems, n_read=len(read))


def _overlaid(column: pd.Series | None, values: pd.Series, n: int) -> pd.Series:
    """``column`` with ``values`` (a few rows' read from their logs; NA: keep the column's)."""
    if column is None:
        return values.reindex(range(n))
    try:
        out = column.copy()
        out.iloc[values.index] = values.combine_first(column.iloc[values.index]).to_numpy()
        return out
    except (TypeError, ValueError):  # values of another type than the column's: let pandas type them
        return values.reindex(range(n)).combine_first(column)


#: ``log_state`` of a row whose log is fine; the others are the problems' kinds.
LOG_OK = "ok"
#: ``log_state`` of a row whose log names another point (swapped or copied on disk).
FOREIGN = "foreign"
#: ``log_state`` of a row whose log's summary is intact but some data is not (a chunk fails its CRC).
DAMAGED = "damaged"
#: ``log_state`` of a row whose log's parameters or outcome differ from the ledger's (either was edited).
DISAGREES = "disagrees"
LOG_STATES = (LOG_OK, "missing", "unreadable", "torn", FOREIGN, DAMAGED, DISAGREES)


def log_states(log_paths: pd.Series, problems: Sequence[Mapping[str, str]]) -> pd.Series:
    """Per row: "ok", or what is wrong with its log ("missing", "unreadable", "torn", "foreign":
    another point's run, "damaged": data chunks unreadable, "disagrees": parameters or outcome
    other than the ledger's), or empty where the point has none (a failed run, an unfinished point)
    — so that the table alone says which metrics a log no longer backs. Categorical, made from
    its codes (no text a row)."""
    kinds = {p["path"]: p["kind"] for p in problems if p["kind"] in LOG_STATES}
    codes = np.full(len(log_paths), -1, dtype=np.int8)
    codes[log_paths.notna().to_numpy()] = LOG_STATES.index(LOG_OK)
    if kinds:
        hit = np.flatnonzero(log_paths.isin(list(kinds)).to_numpy())
        codes[hit] = [LOG_STATES.index(kinds[p]) for p in log_paths.iloc[hit]]
    return pd.Series(pd.Categorical.from_codes(codes, categories=LOG_STATES), index=log_paths.index)


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


def ordered(frame: pd.DataFrame) -> pd.DataFrame:
    """The table's columns in their order: ids, parameters, metrics, then the rest."""
    return frame[[*[c for c in ID_COLUMNS if c in frame.columns], *[c for c in frame.columns if c not in ID_COLUMNS]]]
