"""What ``check-rig`` last measured a link to sustain, kept for ``run`` to warn before a campaign
that asks for more (issue 36: 86 Hz measured on a loaded machine, then a 200 Hz host-loop campaign
ran with 71 late ticks and a failed run without a word).

Where: one JSON file per user and machine, ``$XDG_CACHE_HOME/labrunner/check-rig.json`` (default
``~/.cache/labrunner/``; ``LABRUNNER_CACHE`` names another folder). Not next to the rig file: a
measurement belongs to this machine and its load, and a rig file may sit in a read-only checkout
or be shared by several hosts. An entry is keyed by the rig file's absolute path and its link (the
serial port, or the CAN interface and channel, as the command line or the file gave them) and holds
the highest host-loop f_s [Hz] that check-rig found sustainable with margin, and when. A record
that cannot be read is treated as absent; one that cannot be written costs a one-line note, never
the check itself.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from labrunner.rigs.config import LINK_KEYS

RECORD_NAME = "check-rig.json"


def record_path() -> Path:
    """The record file (module docstring)."""
    folder = os.environ.get("LABRUNNER_CACHE")
    if not folder:
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        folder = str(Path(base) / "labrunner")
    return Path(folder) / RECORD_NAME


def link_key(rig_file: str | os.PathLike, kind: str, parameters: Mapping[str, Any]) -> str:
    """The entry of a rig file (absolute path) on its link (:data:`~labrunner.rigs.config.LINK_KEYS`)."""
    link = {k: parameters.get(k) for k in LINK_KEYS.get(kind, ())}
    return json.dumps([str(Path(rig_file).resolve()), link], sort_keys=True)


def _entries() -> dict[str, Any]:
    try:
        data = json.loads(record_path().read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def remember(key: str, max_host_fs: float) -> None:
    """Keep check-rig's sustainable host-loop f_s [Hz] for ``key`` (written atomically)."""
    entries = _entries()
    entries[key] = {"max_host_fs": float(max_host_fs), "measured_at": time.time()}
    path = record_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(entries, indent=1, sort_keys=True), encoding="utf-8")
    os.replace(tmp, path)


def last(key: str) -> dict[str, float] | None:
    """The last measurement of ``key`` (``max_host_fs`` [Hz], ``measured_at`` [s since 1970]), or None."""
    entry = _entries().get(key)
    if not isinstance(entry, dict):
        return None
    try:
        return {"max_host_fs": float(entry["max_host_fs"]), "measured_at": float(entry["measured_at"])}
    except (KeyError, TypeError, ValueError):
        return None


def warning(key: str, fs: float) -> str:
    """One line when a host-loop campaign at ``fs`` [Hz] asks more than check-rig last measured; "" else."""
    found = last(key)
    if found is None or fs <= found["max_host_fs"]:
        return ""
    when = time.strftime("%Y-%m-%d %H:%M", time.localtime(found["measured_at"]))
    return (
        f"warning: f_s = {fs:g} Hz exceeds the {found['max_host_fs']:.0f} Hz the host loop sustained on this link "
        f"when `labrunner check-rig` last measured it ({when}); expect late ticks and failed runs: lower f_s, "
        'use loop = "device", or measure again'
    )
