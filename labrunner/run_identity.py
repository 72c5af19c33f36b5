"""Which point a run log belongs to, proved by the log itself (light: no log reader until one is read).

A log's file name (``runs/<point_id>.mcap``) is only where it was published; two logs swapped or
copied on disk keep their names and change their content. Whoever reads a log for a ledger row
therefore checks the point id the log's own ``run`` record names (written by the worker with the
signals, read through :func:`~labrunner.logs.read_metadata` or :func:`~labrunner.logs.read_run`'s
metadata, whatever the file's layout) against the row's id: :func:`mismatch` says how they differ.

Reading every log's metadata costs ~0.8 ms a log (13 min at 10^6 points), so the ledger also records
each published log's :func:`fingerprint` — size, mtime, ctime and inode, taken after the log was
written (or, by ``repair`` and recovery, before it was read and proved): a file at the same path
with the same fingerprint is that very file, unchanged since, and needs no reading. Any change
gives another fingerprint: a swap with ``mv`` brings another inode (and the other file's size and
mtime), a copy or an edit a new ctime — which no user tool can set back, unlike mtime. A
fingerprint that differs proves nothing either way; the log is then read as before.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any

from labrunner.errors import LabrunnerError

#: The ledger's columns for a log's :func:`fingerprint`, in its order.
FINGERPRINT_COLUMNS = ("log_size", "log_mtime_ns", "log_ctime_ns", "log_inode")

Fingerprint = tuple[int, int, int, int]


def fingerprint(path: str | os.PathLike[str]) -> Fingerprint:
    """(size, mtime [ns], ctime [ns], inode) of the file at ``path`` (see the module); OSError if absent."""
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino


class ForeignLog(LabrunnerError):
    """A log read for one point is another point's run (or names none)."""


class UntrustedLog(LabrunnerError):
    """A log that does not back its ledger row: damaged, or saying other than the ledger."""


def disagreement(
    metadata: Mapping[str, Any],
    status: str | None,
    parameters: Mapping[str, Any],
    outcome: str | None,
    metrics: Mapping[str, Any] | None = None,
) -> str:
    """ "" if a log's ``metadata`` and outcome ``status`` agree with its ledger row (the point's
    ``parameters``, its ``outcome``, and the ``metrics`` committed with it when given), else what
    differs: a parameter edited in the ledger, or a bit flipped in the log's metadata (whose
    records carry no checksum of their own: the ledger, written from the same run, is the check)."""
    logged = metadata.get("parameters")  # absent from logs written without one (older, by hand): not compared
    if logged is not None and (not isinstance(logged, Mapping) or set(logged) != set(parameters)):
        shown = sorted(logged) if isinstance(logged, Mapping) else logged
        return f"the log's parameters are {shown!r}, the ledger's {sorted(parameters)}"
    config = metadata.get("config")
    config = config if isinstance(config, Mapping) else {}
    for key, value in parameters.items():
        if logged is not None and not _same(logged[key], value):
            return f"{key} is {logged[key]!r} in the log, {value!r} in the ledger"
        section, _, name = key.rpartition(".")
        table = config.get(section) if section else config
        if isinstance(table, Mapping) and name in table and not _same(table[name], value):
            return f"{key} is {table[name]!r} in the log's config, {value!r} in the ledger"
    if outcome is not None and status is not None and status != outcome:
        return f"the log's outcome is {status!r}, the ledger's {outcome!r}"
    logged_metrics = metadata.get("metrics")
    if metrics and isinstance(logged_metrics, Mapping):
        for key, value in metrics.items():
            if key in logged_metrics and not _same(logged_metrics[key], value):
                return f"metric {key} is {logged_metrics[key]!r} in the log, {value!r} in the ledger"
    return ""


def _same(a: Any, b: Any) -> bool:
    """Equal, numbers to 1e-12 relative (both written from one float), NaN and None alike."""
    missing = (None, "nan", "NaN")
    if isinstance(a, float) and math.isnan(a) or a in missing:
        return isinstance(b, float) and math.isnan(b) or b in missing
    if (
        isinstance(a, (int, float))
        and isinstance(b, (int, float))
        and not isinstance(a, bool)
        and not isinstance(b, bool)
    ):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=0.0)
    return a == b


def named_point(metadata: Mapping[str, Any]) -> str | None:
    """The point id a log's metadata records (its ``run`` record), None if it records none."""
    run = metadata.get("run")
    value = run.get("point_id") if isinstance(run, Mapping) else None
    return value if isinstance(value, str) else None


def mismatch(metadata: Mapping[str, Any], point_id: str) -> str:
    """ "" if the log's metadata names ``point_id``, else why it cannot back that point."""
    return describe(named_point(metadata), point_id)


def describe(named: str | None, point_id: str) -> str:
    """ "" if a log that names point ``named`` may back point ``point_id``, else why not."""
    if named == point_id:
        return ""
    if named is None:
        return f"point {point_id}: the log names no point"
    return f"point {point_id}: the log is point {named}'s run (logs swapped or copied?)"


def check(metadata: Mapping[str, Any], point_id: str, path: str | os.PathLike[str]) -> None:
    """Raise :class:`ForeignLog` (naming ``path``) unless the log's metadata names ``point_id``."""
    problem = mismatch(metadata, point_id)
    if problem:
        raise ForeignLog(f"{os.fspath(path)}: {problem}")


def read_named_point(path: str | os.PathLike[str]) -> str | None:
    """The point id the log at ``path`` names (its metadata only, not its signals)."""
    from labrunner.logs import read_metadata

    return named_point(read_metadata(path))
