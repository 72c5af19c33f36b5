"""Shared helpers of the guided-campaign tests (no tests here): campaign files with a [guided] section."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from test_campaign_support import campaign_text


def toml_value(value: Any) -> str:
    """A TOML value: numbers, strings and booleans as JSON writes them, tables inline."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)


def guided_text(
    guided: dict[str, Any],
    *,
    name: str = "tiny",
    grid: dict[str, Any] | None = None,
    rig: str = "dcmotor-sim",
    duration: float = 2.0,
) -> str:
    """:func:`test_campaign_support.campaign_text` (first-order MFC of the motor's velocity) with
    ``[guided]`` instead of its grid (or both, with ``grid``)."""
    head = campaign_text(name, rig=rig, duration=duration).split("[grid]")[0]
    lines = [head, "[guided]"] + [f"{k} = {toml_value(v)}" for k, v in guided.items()]
    if grid:
        lines += ["", "[grid]"] + [f"{json.dumps(k)} = {toml_value(v)}" for k, v in grid.items()]
    return "\n".join(lines) + "\n"


def write_campaign(folder: Path, guided: dict[str, Any], **kw: Any) -> Path:
    """A campaign file in ``folder`` (a project: it gets a pyproject.toml marker)."""
    (folder / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    path = folder / f"{kw.get('name', 'tiny')}.toml"
    path.write_text(guided_text(guided, **kw))
    return path
