"""Ledger rows into the metrics table's columns, a chunk of rows at a time (issue 34 part 5).

Each chunk is built a column at a time, not a record a row: the ledger's JSON texts of a column
are parsed together — the metrics (the widest: ~360 bytes a row) by Arrow's JSON reader straight
into typed arrays, parameters likewise, outcomes by one ``json.loads`` of the chunk's distinct texts joined
as an array (an outcome's columns are worked out once per distinct text) — and each column is handed to pandas as one list or array. The result is the frame of
per-row records the table was built from before (``pd.DataFrame.from_records``), value for value
and type for type (tests/test_analysis_table_rows.py checks it against that path): where Arrow
would type a metric otherwise (a text, a boolean, a number and a boolean in one column) the
chunk's metrics are parsed as the parameters are. With the rows read column-wise
(:func:`ledger_chunks`: no dict a row), the whole ``table()`` of a 10^5-point campaign took
3.0 s of CPU where the per-row path took 8.3 s, in the same minute on the shared 2-core machine
(benchmarks/bench_table.py).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import sqlite3
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner.campaign import integrity
from labrunner.campaign.rig_timing import timing_counts
from labrunner.rigs.device.lawflag import arithmetic_of, flag_of
from labrunner.run_identity import FINGERPRINT_COLUMNS

#: The ledger's own metric columns (older ledgers hold only these, no ``metrics_json``).
LEDGER_METRICS = ("rms_error", "input_energy", "max_abs_input")
#: Ledger rows turned into table rows at a time: the Python objects of one chunk (~4.6 kB a row
#: while it is turned into columns, ~46 MB) are freed before the next is read, so that building the
#: table of 10^6 points holds one chunk's, not all; pandas' fixed cost a column a chunk made 2000
#: rows a chunk ~20 % slower at 10^5 (benchmarks/bench_table.py).
CHUNK_ROWS = 10_000
#: A chunk of ledger rows, column-wise: column name → one value a row.
Chunk = Mapping[str, Sequence[Any]]
#: The ledger columns the table reads (an older ledger lacks some: read as None).
LEDGER_COLUMNS = (
    "seq",
    "id",
    "state",
    "outcome",
    "outcome_json",
    "parameters",
    "metrics_json",
    "log_path",
    "attempts",
    *LEDGER_METRICS,
    *FINGERPRINT_COLUMNS,
)


def ledger_chunks(db: sqlite3.Connection) -> Iterator[dict[str, list[Any]]]:
    """The ledger's points in grid order, :data:`CHUNK_ROWS` at a time, column-wise: one tuple a
    row from SQLite, transposed (a dict a row would cost as much as the rest of the table)."""
    present = {r[1] for r in db.execute("PRAGMA table_info(points)")}
    names = [c for c in LEDGER_COLUMNS if c in present]
    # the ledger's own metrics only where no stored metrics replace them (a float object a row less)
    own = (
        "CASE WHEN metrics_json IS NULL OR metrics_json = '' THEN {0} END AS {0}"
        if "metrics_json" in present
        else "{0}"
    )
    cursor = db.execute(
        f"SELECT {', '.join(own.format(c) if c in LEDGER_METRICS else c for c in names)} FROM points ORDER BY seq"
    )
    cursor.row_factory = None
    while rows := cursor.fetchmany(CHUNK_ROWS):
        yield dict(zip(names, map(list, zip(*rows))))


@contextlib.contextmanager
def verified_chunks(db: sqlite3.Connection, path: Path) -> Iterator[Iterator[Chunk]]:
    """:func:`ledger_chunks` of a ledger opened with ``per_row=False`` (its other checks passed),
    with the ids' and parameters' checks (:class:`~labrunner.campaign.integrity.RowDigests`) taken
    over the rows as they stream past instead of in two more passes (~3 s of a 10^6-point table's
    CPU); the rows and the checksums they are held against are read in one snapshot. A ledger that
    fails raises :class:`~labrunner.campaign.integrity.LedgerDamaged` once every row is read (the
    rows the caller was given are then not to be used), as does a row the caller could not read
    (parameters edited into something that is no JSON object: the full checks name it)."""
    digests = integrity.RowDigests()
    db.execute("BEGIN")  # one read snapshot: a guided round adding rows meanwhile is not half-seen
    try:
        meta = dict(db.execute("SELECT key, value FROM meta").fetchall())

        def chunks() -> Iterator[Chunk]:
            for chunk in ledger_chunks(db):
                digests.add(chunk["id"], chunk["parameters"])
                yield chunk
            integrity.verify_digests(digests, meta, path)

        stream = chunks()
        try:
            yield stream
            for _ in stream:  # the checks run once every row is read
                pass
        except integrity.LedgerDamaged:
            raise
        except Exception:
            integrity.verify(db, path)  # a row the caller could not read: is it the ledger?
            raise
    finally:
        db.execute("COMMIT")


def in_chunks(rows: Iterable[Mapping[str, Any]]) -> Iterator[dict[str, list[Any]]]:
    """Rows as mappings (``dict(sqlite3.Row)``) cut into column-wise chunks, as :func:`ledger_chunks` gives them."""
    iterator = iter(rows)
    while chunk := list(itertools.islice(iterator, CHUNK_ROWS)):
        yield {k: [r.get(k) for r in chunk] for k in dict.fromkeys(itertools.chain(*chunk))}


_SCALARS = (int, float, str, bool)


def as_float(value: Any) -> float:
    """``value`` as a float, NaN for None."""
    return float(value) if value is not None else float("nan")


def parsed(texts: Sequence[str | None]) -> list[Any]:
    """Every JSON text of a chunk's column, parsed in one call (an array of them: half the cost of a
    ``json.loads`` each); an empty or missing text is ``None``."""
    return json.loads("[" + ",".join(t or "null" for t in texts) + "]")


def _arrow_table(texts: Sequence[str]) -> Any:
    """JSON objects, one a text, as an Arrow table (a column a key, in the order keys first
    appear); None where Arrow cannot read them as such."""
    import pyarrow as pa
    import pyarrow.json as pj

    options = pj.ReadOptions(use_threads=False, block_size=1 << 26)
    try:
        return pj.read_json(io.BytesIO("\n".join(texts).encode()), read_options=options)
    except pa.ArrowInvalid:
        return None


def _arrow_parameters(texts: Sequence[str]) -> dict[str, list[Any]] | None:
    """The parameters of a chunk's rows, their scalars only (a list or table is no column), as
    columns from Arrow's reading; None (read them a row at a time) unless every row gives every
    key a number, a text or a boolean (Arrow would make a date of a text that looks like one)."""
    import pyarrow as pa

    table = _arrow_table(texts)
    if table is None:
        return None
    columns = {}
    for name, column in zip(table.column_names, table.columns):
        kind = column.type
        if column.null_count:
            return None
        if (
            pa.types.is_integer(kind)
            or pa.types.is_floating(kind)
            or pa.types.is_string(kind)
            or pa.types.is_boolean(kind)
        ):
            columns[name] = column.to_pylist()
        elif not (pa.types.is_list(kind) or pa.types.is_struct(kind)):
            return None
    return columns


def _parameter_columns(texts: Sequence[str]) -> tuple[dict[str, Any], list[tuple[str, ...]]]:
    """The chunk's parameter columns (scalars only; NaN where a row lacks a key) and each row's
    keys in its order: from Arrow (every row the same keys) or, failing it, a record a row."""
    columns = _arrow_parameters(texts)
    if columns is not None:
        return columns, [tuple(columns)] * len(texts)
    rows = [{k: v for k, v in p.items() if isinstance(v, _SCALARS)} for p in parsed(texts)]
    shapes = [tuple(r) for r in rows]
    return {k: [r.get(k, np.nan) for r in rows] for k in dict.fromkeys(itertools.chain(*shapes))}, shapes


def _arrow_metrics(texts: Sequence[str]) -> dict[str, np.ndarray] | None:
    """The metrics texts of a chunk as one float or integer array per key (NaN where a row stores
    null or lacks the key), keys in the order they first appear; None where a metric is not a
    number in every row (then :func:`parsed` types it, as a record a row would)."""
    import pyarrow as pa

    table = _arrow_table(texts)
    if table is None:
        return None
    out: dict[str, np.ndarray] = {}
    for name, column in zip(table.column_names, table.columns):
        kind = column.type
        if pa.types.is_null(kind):
            out[name] = np.full(len(column), np.nan)
        elif pa.types.is_integer(kind) or pa.types.is_floating(kind):
            values = column.to_numpy()  # an integer column with a null comes as floats with NaN
            out[name] = values.astype(float) if pa.types.is_floating(kind) else values
        else:
            return None
    return out


def _metric_columns(chunk: Chunk, texts: Sequence[str | None]) -> tuple[dict[str, Any], list[tuple[str, ...]]] | None:
    """The chunk's metric columns — rows without stored metrics hold the ledger's own columns
    (:data:`LEDGER_METRICS`), NaN elsewhere — and each row's metric names in its order; None:
    see :func:`_arrow_metrics`."""
    have = [i for i, t in enumerate(texts) if t]
    stored = _arrow_metrics([texts[i] for i in have]) if have else {}
    if stored is None:
        return None
    names = tuple(stored)
    shapes = [names if t else LEDGER_METRICS for t in texts]
    if len(have) == len(texts):
        return stored, shapes
    lacking = [i for i, t in enumerate(texts) if not t]
    out: dict[str, Any] = {}
    for key in dict.fromkeys([*names, *LEDGER_METRICS]):
        column = out[key] = np.full(len(texts), np.nan)
        if key in stored:
            column[have] = stored[key]
        if key in LEDGER_METRICS:
            own = _column(chunk, key)
            column[lacking] = [as_float(own[i]) for i in lacking]
    return out, shapes


def _per_row_metrics(chunk: Chunk, texts: Sequence[str | None]) -> tuple[dict[str, Any], list[tuple[str, ...]]]:
    """:func:`_metric_columns` typed as a record a row would type them (a metric that is not a number)."""
    own = list(zip(*(_column(chunk, k) for k in LEDGER_METRICS)))
    per_row = [
        dict(zip(LEDGER_METRICS, map(as_float, own[i])))
        if m is None
        else {k: np.nan if v is None else v for k, v in m.items()}  # null: undefined (older ledgers: NaN)
        for i, m in enumerate(parsed(texts))
    ]
    shapes = [tuple(m) for m in per_row]
    return {k: [m.get(k, np.nan) for m in per_row] for k in dict.fromkeys(itertools.chain(*shapes))}, shapes


def _column(chunk: Chunk, name: str) -> Sequence[Any]:
    """A column of the chunk, None in every row where the ledger has no such column (an older one)."""
    values = chunk.get(name)
    return values if values is not None else [None] * len(chunk["seq"])


def chunk_frame(chunk: Chunk) -> tuple[pd.DataFrame, list[int]]:
    """One chunk of ledger rows as the table's columns (see the module): ids, outcome and its
    details, parameters (scalars), metrics, a real rig's timing counts; and the positions of
    finished rows whose ledger holds no full metrics (their logs must be read)."""
    columns, missing = chunk_columns(chunk)
    return pd.DataFrame(columns), missing


def chunk_columns(chunk: Chunk) -> tuple[dict[str, Any], list[int]]:
    """:func:`chunk_frame`'s columns before they are a frame (name → a list or array each):
    the table joins them a column at a time, so a frame of each chunk would be built, its blocks
    consolidated, and every column copied out again for nothing."""
    n = len(chunk["seq"])
    # an outcome's columns once per distinct text (a completed run's is the same in every such row)
    distinct = dict.fromkeys(chunk["outcome_json"])
    which = np.fromiter(map({t: k for k, t in enumerate(distinct)}.__getitem__, chunk["outcome_json"]), np.intp, n)
    outcomes = [o or {} for o in parsed(list(distinct))]
    timing = [timing_counts(o.get("diagnostics")) if "diagnostics" in o else {} for o in outcomes]
    aborted = np.array(chunk["outcome"], dtype=object) == "aborted"
    texts = _column(chunk, "metrics_json")
    missing = [i for i, (t, p) in enumerate(zip(texts, chunk["log_path"])) if not t and p]
    params, param_shapes = _parameter_columns(chunk["parameters"])

    def per_row(values: list[Any], dtype: Any = object) -> np.ndarray:
        return np.array(values, dtype=dtype)[which]

    columns: dict[str, Any] = {
        "seq": chunk["seq"],
        "id": chunk["id"],
        "outcome": [o or s for o, s in zip(chunk["outcome"], chunk["state"])],
        "monitor": per_row([o.get("monitor") for o in outcomes]),
        "abort_time": np.where(aborted, per_row([as_float(o.get("time")) for o in outcomes], float), np.nan),
        "abort_value": np.where(aborted, per_row([as_float(o.get("value")) for o in outcomes], float), np.nan),
        "attempts": chunk["attempts"],
        "log_path": chunk["log_path"],
        "torn": np.zeros(n, dtype=bool),
        "law_check": per_row([flag_of(o) if "diagnostics" in o else "" for o in outcomes]),
        "law_arithmetic": per_row([arithmetic_of(o) if "diagnostics" in o else "" for o in outcomes]),
    }
    metrics, shapes = _metric_columns(chunk, texts) or _per_row_metrics(chunk, texts)
    # the other columns in the order their names first appear in the rows' parameters, metrics and
    # timing counts (as a frame of per-row records orders them; distinct shapes of rows are few)
    timed = dict.fromkeys(itertools.chain(*dict.fromkeys(map(tuple, timing))))
    order = dict.fromkeys(zip(param_shapes, shapes, (tuple(timing[k]) for k in which)))
    for key in dict.fromkeys(itertools.chain.from_iterable(itertools.chain(*shape) for shape in order)):
        if key in metrics:
            columns[key] = metrics[key]
        elif key in timed:
            columns[key] = per_row([d.get(key, np.nan) for d in timing], None)  # counts: NumPy types them
        else:
            columns[key] = params[key]
    return columns, missing
