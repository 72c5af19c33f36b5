"""The metrics table's files: ``metrics.csv`` and ``metrics.parquet`` in the report folder.

Both are written :data:`ROWS_AT_A_TIME` rows at a time from the table in memory (a row group of
the Parquet file each), so that writing 10^6 rows never holds a second
copy of the table: log paths are made relative to the report folder and categorical columns
written as plain text chunk by chunk. The files are the same as one ``to_csv`` / ``to_parquet``
of the whole table (tests/test_analysis_table_files.py). Each is written under a temporary name
and renamed into place.
"""

from __future__ import annotations

import os
from pathlib import Path

import pandas as pd

from labrunner import safefs
from labrunner.analysis.table import METRICS_VERSION, ordered

METRICS_CSV = "metrics.csv"
#: Rows written at a time (~8 MB of them as text at the motor campaign's width of ~40 columns).
ROWS_AT_A_TIME = 20_000
#: The table with its types; the next analysis reuses its rows (see :func:`~labrunner.analysis.table.build_table`).
METRICS_PARQUET = "metrics.parquet"


def relative_paths(paths: pd.Series, directory: Path, out: Path) -> pd.Series:
    """Campaign-relative paths as seen from the folder ``out`` (None stays None)."""
    base = os.path.relpath(directory.resolve(), out.resolve())
    return paths.map(lambda p: os.path.join(base, p) if isinstance(p, str) else p)


def as_written(frame: pd.DataFrame, directory: Path, out: Path) -> pd.DataFrame:
    """Rows of the table as the files hold them: columns in order, log paths relative to ``out``,
    categorical and other text columns as strings, and last the ``metrics_version`` (the next
    analysis reuses rows of this version only)."""
    table = ordered(frame.assign(log_path=relative_paths(frame["log_path"], directory, out)))
    table = table.assign(metrics_version=METRICS_VERSION)
    text = {c: "str" for c in table.columns if isinstance(table[c].dtype, pd.CategoricalDtype)}
    return table.astype({**text, **{c: "string" for c in table.columns if table[c].dtype == object}})


def write_table(frame: pd.DataFrame, out: Path, directory: Path) -> tuple[Path, Path]:
    """Write ``metrics.csv`` and ``metrics.parquet`` into ``out`` (see the module)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    safefs.mkdir(out, parents=True)
    csv, parquet = out / METRICS_CSV, out / METRICS_PARQUET
    # temporary files under unpredictable names (O_EXCL), renamed over regular files only (labrunner.safefs)
    with safefs.atomic_path(csv) as tmp_csv, safefs.atomic_path(parquet) as tmp_parquet:
        writer = None
        try:
            with open(tmp_csv, "w", newline="", encoding="utf-8") as fh:
                for start in range(0, max(len(frame), 1), ROWS_AT_A_TIME):
                    chunk = as_written(frame.iloc[start : start + ROWS_AT_A_TIME], directory, out)
                    with safefs.naming(csv):  # a full disk names the file it filled
                        chunk.to_csv(fh, index=False, header=start == 0)
                    batch = pa.Table.from_pandas(chunk, preserve_index=False, schema=writer and writer.schema)
                    with safefs.naming(parquet):
                        writer = writer or pq.ParquetWriter(tmp_parquet, batch.schema)
                        writer.write_table(batch)
        finally:
            if writer is not None:
                writer.close()
    return csv, parquet
