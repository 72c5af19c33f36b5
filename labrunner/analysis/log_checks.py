"""Which logs of a campaign's metrics table are there, whole and their own point's, and which must be read.

Every log a ledger row names is checked (:class:`LogChecks`, fed one chunk of ledger rows at a
time, so that a campaign of 10^6 points keeps two integers a row and the positions of the few rows
that need more):

- it exists, else it is ``missing``;
- it is its own point's run (:mod:`labrunner.run_identity`), and whole: proved by one ``stat``
  when its fingerprint is the one the ledger recorded when the run was committed (a log is
  fingerprinted only once complete, and any change since gives another fingerprint);
- otherwise it is opened: whole when it begins and ends with the MCAP magic (a writer killed
  mid-file leaves no closing magic; two 8-byte reads, else it is read, to salvage and flag it),
  its own when the previous analysis's table proved this very file (same size and mtime), else
  it is read (:func:`identity`): the point it names, its data chunks (a damaged one is flagged,
  not believed), and its parameters and outcome against the ledger row's (:attr:`LogChecks.expected`).

The ``stat`` alone matters at scale: the two reads of the magic cost a disk read each for logs
not in the page cache, ~0.2 ms apiece: 400 s of a 10^6-point table, against ~16 s of ``stat``.

The previous table (``metrics.parquet``) is read only for the rows that need it, one row group at
a time (:func:`cached_rows`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner import run_identity
from labrunner.errors import LabrunnerError
from labrunner.run_identity import FINGERPRINT_COLUMNS, Fingerprint

#: Table columns that tell which file (size, mtime) backed a row: what the next analysis compares.
CACHE_COLUMNS = ("log_size", "log_mtime_ns")
#: Parallel reading pays off above this many logs.
_PARALLEL_MIN = 64
_MAGIC = b"\x89MCAP0\r\n"


def fingerprints(directory: Path, paths: Sequence[str | None]) -> list[Fingerprint | None]:
    """:func:`~labrunner.run_identity.fingerprint` of each path (relative to ``directory``, or
    absolute), None where there is no path or no file: one ``stat`` each in one loop, relative to
    the directory's descriptor (no path joined a row, a shorter lookup; no function call a row)."""
    out: list[Fingerprint | None] = []
    append, stat = out.append, os.stat
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        for path in paths:
            if not path:
                append(None)
                continue
            try:
                st = stat(path, dir_fd=fd)  # an absolute path is taken as such (fstatat)
            except OSError:
                append(None)
                continue
            append((st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino))
    finally:
        os.close(fd)
    return out


def _opened(path: str) -> tuple[Fingerprint, bool] | None:
    """(fingerprint, intact) of a log whose fingerprint is not the recorded one, None if it is
    missing: whole when it begins and ends with the MCAP magic (see the module)."""
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
    return (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino), intact


def _cell(rows: Mapping[str, Sequence[Any] | None], column: str, i: int) -> Any:
    """Row ``i``'s value of ``column`` in a column-wise chunk (None where the ledger lacks it)."""
    values = rows.get(column)
    return None if values is None else values[i]


@dataclass
class LogChecks:
    """The checks of every log a table's ledger rows name (see the module); positions are the
    rows' in the whole table. ``recompute``: every log is to be read for its metrics."""

    directory: Path
    recompute: bool = False
    problems: list[dict[str, str]] = field(default_factory=list)  # {"path", "kind", "detail"}
    todo: list[int] = field(default_factory=list)  # rows whose metrics come from their log (or the cache)
    no_metrics: set[int] = field(default_factory=set)  # … because the ledger holds none of them
    unproved: list[int] = field(default_factory=list)  # other rows whose log's identity is not proved yet
    fingerprinted: set[int] = field(default_factory=set)  # todo rows the ledger's fingerprint proves
    #: (parameters, outcome, metrics JSON) of the rows whose fingerprint does not prove their log,
    #: which is read and must agree with them (a few rows in a normal campaign; every row of an old ledger)
    expected: dict[int, tuple[str, str | None, str | None]] = field(default_factory=dict)
    _sizes: list[np.ndarray] = field(default_factory=list)
    _mtimes: list[np.ndarray] = field(default_factory=list)

    def add(self, start: int, rows: Mapping[str, Sequence[Any]], no_metrics: Collection[int]) -> None:
        """Check the logs of ``rows`` (a column-wise chunk of ledger rows from position ``start``
        on); ``no_metrics``: positions in it of finished rows whose ledger holds no full metrics."""
        n = len(rows["id"])
        size = np.full(n, -1, dtype=np.int64)
        mtime = size.copy()
        root = str(self.directory) + os.sep  # joined as text: a tenth of pathlib's cost a row
        rels = rows["log_path"]
        found = fingerprints(self.directory, rels)
        recorded = list(zip(*(rows.get(c) or [None] * n for c in FINGERPRINT_COLUMNS)))
        # a row whose log has its recorded fingerprint is proved and whole, and needs nothing more
        # unless its metrics are to be read: only the others are looked at one by one
        wanted = set(no_metrics)
        for i in range(n) if self.recompute else sorted({i for i in range(n) if found[i] != recorded[i]} | wanted):
            rel = rels[i]
            if not rel:
                continue
            proved = found[i] is not None and found[i] == recorded[i]
            st = (found[i], True) if proved else _opened(rel if rel.startswith(os.sep) else root + rel)
            if st is None:
                self.problems.append(
                    {"path": rel, "kind": "missing", "detail": f"point {rows['id'][i]}: log file not found"}
                )
                continue
            found[i], intact = st
            proved = recorded[i] == found[i]
            if not proved:
                self.expected[start + i] = (
                    _cell(rows, "parameters", i) or "{}",
                    _cell(rows, "outcome", i),
                    _cell(rows, "metrics_json", i),
                )
            if self.recompute or i in wanted or not intact:
                self.todo.append(start + i)
                if i in wanted:
                    self.no_metrics.add(start + i)
                if proved:
                    self.fingerprinted.add(start + i)
            elif not proved:
                self.unproved.append(start + i)
        stated = [i for i, f in enumerate(found) if f is not None]
        if stated:
            size[stated] = [found[i][0] for i in stated]
            mtime[stated] = [found[i][1] for i in stated]
        self._sizes.append(size)
        self._mtimes.append(mtime)

    def stats(self) -> tuple[np.ndarray, np.ndarray]:
        """Size and mtime [ns] of every row's log (−1: no log, or a missing one); once, the
        chunks' pieces given up as they are joined (16 MB at 10^6 rows, not held twice)."""
        if not self._sizes:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        sizes = np.concatenate(self._sizes)
        self._sizes.clear()
        mtimes = np.concatenate(self._mtimes)
        self._mtimes.clear()
        return sizes, mtimes


def cached_rows(path: Path | None, ids: Collection[str], version: int) -> dict[str, dict[str, Any]]:
    """The rows of ``ids`` in the previous table at ``path`` (``metrics.parquet``), read a row
    group at a time; none when it is absent, unreadable, of another metrics ``version``, or
    lacks :data:`CACHE_COLUMNS`."""
    if path is None or not ids:
        return {}
    try:
        import pyarrow.parquet as pq

        table = pq.ParquetFile(path)
        if not {"id", "metrics_version", *CACHE_COLUMNS} <= set(table.schema_arrow.names):
            return {}
        out: dict[str, dict[str, Any]] = {}
        wanted = list(ids)
        for batch in table.iter_batches(batch_size=20_000):
            frame = batch.to_pandas()
            if not (frame["metrics_version"] == version).all():
                return {}
            hit = frame[frame["id"].isin(wanted)]
            out.update((r["id"], r) for r in hit.to_dict("records"))
        return out
    except (OSError, ValueError, ImportError):
        return {}


def same_file(hit: Mapping[str, Any] | None, stat: tuple[int, int]) -> bool:
    """Whether a cached row was built from a file of this (size, mtime)."""
    if hit is None:
        return False
    size, mtime = hit.get("log_size"), hit.get("log_mtime_ns")
    return bool(pd.notna(size) and pd.notna(mtime)) and (int(size), int(mtime)) == (int(stat[0]), int(stat[1]))


def proved_by_cache(hit: Mapping[str, Any] | None, stat: tuple[int, int], ok: str) -> bool:
    """Whether a cached row says its log, this same file (size, mtime), was proved to be its own
    (its ``log_state`` was ``ok``)."""
    return hit is not None and hit.get("log_state") == ok and same_file(hit, stat)


def named_point(path: str) -> dict[str, Any]:
    """What a log whose fingerprint changed says of itself (:func:`identity`), or ``{"error": ...}``."""
    from labrunner.logs import read_run

    try:
        log = read_run(path)
    except (LabrunnerError, OSError, ValueError, KeyError) as exc:
        return {"error": f"{type(exc).__name__}: {exc}"}
    return identity(log)


def identity(log: Any) -> dict[str, Any]:
    """``{"log_point", "log_damaged", "log_metadata", "log_status"}`` of a read :class:`~labrunner.logs.RunLog`:
    the point it names, what of its data is unreadable ("" if nothing), and what to check against
    its ledger row (:func:`disagrees`)."""
    return {
        "log_point": run_identity.named_point(log.metadata),
        "log_damaged": log.damaged,
        "log_metadata": {k: log.metadata.get(k) for k in ("parameters", "config", "metrics")},
        "log_status": (log.outcome or {}).get("status"),
    }


def disagrees(result: Mapping[str, Any], expected: tuple[str, str | None, str | None] | None) -> str:
    """What a read log (:func:`identity`) says other than its ledger row (parameters, outcome,
    metrics JSON); "" if they agree or the row is not known."""
    if expected is None or "log_metadata" not in result:
        return ""
    import json

    parameters, outcome, metrics = expected
    committed = json.loads(metrics) if metrics else None
    return run_identity.disagreement(
        result["log_metadata"], result["log_status"], json.loads(parameters), outcome, committed
    )


def read_many(
    read: Callable[[str], dict[str, Any]],
    paths: Sequence[str],
    workers: int,
    tick: Callable[[int], None] | None = None,
) -> Iterator[dict[str, Any]]:
    """``read(path)`` of every path in order, in a process pool when there are many."""
    if workers <= 1 or len(paths) < _PARALLEL_MIN:
        for p in paths:
            yield read(p)
            if tick:
                tick(1)
        return
    chunk = max(1, min(64, len(paths) // (workers * 8)))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for result in pool.map(read, paths, chunksize=chunk):
            yield result
            if tick:
                tick(1)
