"""Which point a run log belongs to, proved by the log itself (light: no log reader until one is read).

A log's file name (``runs/<point_id>.mcap``) is only where it was published; two logs swapped or
copied on disk keep their names and change their content. Whoever reads a log for a ledger row
therefore checks the point id the log's own ``run`` record names (written by the worker with the
signals, read through :func:`~labrunner.logs.read_metadata` or :func:`~labrunner.logs.read_run`'s
metadata, whatever the file's layout) against the row's id: :func:`mismatch` says how they differ.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

from labrunner.errors import LabrunnerError


class ForeignLog(LabrunnerError):
    """A log read for one point is another point's run (or names none)."""


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
