"""Ledger rows into the metrics table's columns, a chunk of rows at a time (issue 34 part 5).

Each chunk is built a column at a time, not a record a row: the ledger's JSON texts of a column
are parsed together — the metrics (the widest: ~360 bytes a row) by Arrow's JSON reader straight
into typed arrays, parameters and outcomes by one ``json.loads`` of the chunk's texts joined as
an array — and each column is handed to pandas as one list or array. The result is the frame of
per-row records the table was built from before (``pd.DataFrame.from_records``), value for value
and type for type (tests/test_analysis_table_rows.py checks it against that path): where Arrow
would type a metric otherwise (a text, a boolean, a number and a boolean in one column) the
chunk's metrics are parsed as the parameters are. Per 10^4 rows this takes ~0.1 s where the
per-row path took ~0.9 s (benchmarks/bench_table.py).
"""

from __future__ import annotations

import io
import itertools
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from labrunner.campaign.rig_timing import timing_counts
from labrunner.rigs.device.lawflag import flag_of

#: The ledger's own metric columns (older ledgers hold only these, no ``metrics_json``).
LEDGER_METRICS = ("rms_error", "input_energy", "max_abs_input")
_SCALARS = (int, float, str, bool)


def as_float(value: Any) -> float:
    """``value`` as a float, NaN for None."""
    return float(value) if value is not None else float("nan")


def parsed(texts: Sequence[str | None]) -> list[Any]:
    """Every JSON text of a chunk's column, parsed in one call (an array of them: half the cost of a
    ``json.loads`` each); an empty or missing text is ``None``."""
    return json.loads("[" + ",".join(t or "null" for t in texts) + "]")


def _arrow_metrics(texts: Sequence[str]) -> dict[str, np.ndarray] | None:
    """The metrics texts of a chunk as one float or integer array per key (NaN where a row stores
    null or lacks the key), keys in the order they first appear; None where a metric is not a
    number in every row (then :func:`parsed` types it, as a record a row would)."""
    import pyarrow as pa
    import pyarrow.json as pj

    try:
        table = pj.read_json(
            io.BytesIO("\n".join(texts).encode()), read_options=pj.ReadOptions(use_threads=False, block_size=1 << 26)
        )
    except pa.ArrowInvalid:
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


def _metric_columns(
    rows: Sequence[Mapping[str, Any]], texts: Sequence[str | None]
) -> tuple[dict[str, Any], list[tuple[str, ...]]] | None:
    """The chunk's metric columns — rows without stored metrics hold the ledger's own columns
    (:data:`LEDGER_METRICS`), NaN elsewhere — and each row's metric names in its order; None:
    see :func:`_arrow_metrics`."""
    have = [i for i, t in enumerate(texts) if t]
    stored = _arrow_metrics([texts[i] for i in have]) if have else {}
    if stored is None:
        return None
    names = tuple(stored)
    shapes = [names if t else LEDGER_METRICS for t in texts]
    if len(have) == len(rows):
        return stored, shapes
    out: dict[str, Any] = {}
    for key in dict.fromkeys([*names, *LEDGER_METRICS]):
        column = out[key] = np.full(len(rows), np.nan)
        if key in stored:
            column[have] = stored[key]
        if key in LEDGER_METRICS:
            column[[i for i, t in enumerate(texts) if not t]] = [
                as_float(r.get(key)) for t, r in zip(texts, rows) if not t
            ]
    return out, shapes


def _per_row_metrics(
    rows: Sequence[Mapping[str, Any]], texts: Sequence[str | None]
) -> tuple[dict[str, Any], list[tuple[str, ...]]]:
    """:func:`_metric_columns` typed as a record a row would type them (a metric that is not a number)."""
    per_row = [
        {k: as_float(r.get(k)) for k in LEDGER_METRICS}
        if m is None
        else {k: np.nan if v is None else v for k, v in m.items()}  # null: undefined (older ledgers: NaN)
        for m, r in zip(parsed(texts), rows)
    ]
    shapes = [tuple(m) for m in per_row]
    return {k: [m.get(k, np.nan) for m in per_row] for k in dict.fromkeys(itertools.chain(*shapes))}, shapes


def chunk_frame(rows: Sequence[Mapping[str, Any]]) -> tuple[pd.DataFrame, list[int]]:
    """One chunk of ledger rows as the table's columns (see the module): ids, outcome and its
    details, parameters (scalars), metrics, a real rig's timing counts; and the positions of
    finished rows whose ledger holds no full metrics (their logs must be read)."""
    n = len(rows)
    outcomes = [o or {} for o in parsed([r["outcome_json"] for r in rows])]
    texts = [r.get("metrics_json") for r in rows]
    missing = [i for i, (t, r) in enumerate(zip(texts, rows)) if not t and r.get("log_path")]
    params = [{k: v for k, v in p.items() if isinstance(v, _SCALARS)} for p in parsed([r["parameters"] for r in rows])]
    timing = [timing_counts(o.get("diagnostics")) if "diagnostics" in o else {} for o in outcomes]
    aborted = [r["outcome"] == "aborted" for r in rows]
    columns: dict[str, Any] = {
        "seq": [r["seq"] for r in rows],
        "id": [r["id"] for r in rows],
        "outcome": [r["outcome"] or r["state"] for r in rows],
        "monitor": [o.get("monitor") for o in outcomes],
        "abort_time": [as_float(o.get("time")) if a else np.nan for o, a in zip(outcomes, aborted)],
        "abort_value": [as_float(o.get("value")) if a else np.nan for o, a in zip(outcomes, aborted)],
        "attempts": [r["attempts"] for r in rows],
        "log_path": [r["log_path"] for r in rows],
        "torn": [False] * n,
        "law_check": [flag_of(o) if "diagnostics" in o else "" for o in outcomes],
    }
    metrics, shapes = _metric_columns(rows, texts) or _per_row_metrics(rows, texts)
    # the other columns in the order their names first appear in the rows' parameters, metrics and
    # timing counts (as a frame of per-row records orders them; distinct shapes of rows are few)
    timed = dict.fromkeys(itertools.chain(*dict.fromkeys(map(tuple, timing))))
    order = dict.fromkeys(zip(map(tuple, params), shapes, map(tuple, timing)))
    for key in dict.fromkeys(itertools.chain.from_iterable(itertools.chain(*shape) for shape in order)):
        if key in metrics:
            columns[key] = metrics[key]
        else:
            columns[key] = [d.get(key, np.nan) for d in (timing if key in timed else params)]
    return pd.DataFrame(columns), missing
