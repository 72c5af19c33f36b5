"""A real rig's timing a user sees: the late ticks and overruns of each run, read from the
``diagnostics`` record its outcome keeps (docs/protocol.md § Diagnostics, docs/device-loop.md), for
``status`` (in SQL, no JSON parsed in Python), the metrics table (``late_ticks``, ``overruns``
columns), ``analyse`` and the report. Standard library only: ``status`` stays light.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

#: Where a run's ``diagnostics`` record keeps its timing counts, first found wins: the host loop's
#: ``host`` counters, a device-loop run's ``device_loop`` figures (its inputs are never late).
TIMING_PATHS: dict[str, tuple[tuple[str, ...], ...]] = {
    "late_ticks": (("host", "late_ticks"),),
    "overruns": (("host", "overruns"), ("device_loop", "overruns")),
}


def timing_counts(diagnostics: Mapping[str, Any] | None) -> dict[str, int]:
    """``late_ticks`` and ``overruns`` of one real-rig run from its ``diagnostics`` record; ``{}``
    for a twin run, or a failed device-loop run whose device never sent its verdict."""
    if not isinstance(diagnostics, Mapping):
        return {}
    out: dict[str, int] = {}
    for name, paths in TIMING_PATHS.items():
        for path in paths:
            value: Any = diagnostics
            for key in path:
                value = value.get(key) if isinstance(value, Mapping) else None
            if isinstance(value, (int, float)):
                out[name] = int(value)
                break
    if "overruns" in out:
        out.setdefault("late_ticks", 0)  # a device-loop run: no input comes from the host
    return out


def timing_sql(name: str, column: str = "outcome_json") -> str:
    """SQLite expression of :data:`TIMING_PATHS` ``name`` in a stored outcome (NULL without it)."""
    paths = [f"json_extract({column}, '$.diagnostics.{'.'.join(path)}')" for path in TIMING_PATHS[name]]
    if name == "late_ticks":
        paths += [f"CASE WHEN {timing_sql('overruns', column)} IS NOT NULL THEN 0 END"]
    return f"COALESCE({', '.join(paths)})"


def timing_line(timing: Mapping[str, int]) -> str:
    """One line for ``status``, ``analyse`` and the report: the rig's late ticks and overruns."""
    return (
        f"timing on the rig: {timing['late_ticks']} late tick(s) in {timing['runs_with_late_ticks']} run(s), "
        f"{timing['overruns']} overrun(s) in {timing['runs_with_overruns']} run(s), of {timing['runs']} run(s) "
        "(a late tick held the previous input; an overrun is a tick the device computed late)"
    )
