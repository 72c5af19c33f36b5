"""A campaign's free metadata: the ``[metadata]`` table of its file (operator, sample, notes, tags, …).

Researchers attach who ran an experiment, on what sample and why (QCoDeS ``add_metadata``, a
Bluesky start document's metadata). labrunner does not interpret these fields: they do not change
what runs (not part of the plan or its checksum), and they are kept where the results are read —
the ledger's ``meta`` (key ``metadata``, JSON), every run log (its ``metadata`` record), the results
API (``CampaignResults.metadata``, ``RunResults.campaign_metadata``) — and can be searched across
campaigns (``Catalog.search``).

Values are what JSON keeps without loss: strings, booleans, integers, finite numbers, TOML dates
and times (kept as ISO 8601 text), and flat lists of those (tags). Nested tables are refused, as
are keys that are not simple names; sizes are bounded so that a log's metadata stays small.
"""

from __future__ import annotations

import datetime
import math
import re
from collections.abc import Mapping
from typing import Any

from labrunner.errors import InvalidParameter

KEY_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,63}")
MAX_KEYS = 64
MAX_TEXT = 4096  # characters of one string value
MAX_ITEMS = 256  # items of one list value
#: What the error for an unknown ``[campaign]`` key adds: where such fields belong.
HINT = "your own fields (operator, sample, notes, tags, …) go in a [metadata] table"


def parse(table: Any) -> dict[str, Any]:
    """The validated ``[metadata]`` table (module docstring); a clear one-line error naming the key otherwise."""
    if not isinstance(table, Mapping):
        raise InvalidParameter("metadata", f"must be a table of key = value, got {type(table).__name__}")
    if len(table) > MAX_KEYS:
        raise InvalidParameter("metadata", f"at most {MAX_KEYS} keys, got {len(table)}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        if not KEY_RE.fullmatch(key):
            raise InvalidParameter(
                f"metadata.{key}", "keys are names: a letter or _, then letters, digits, _ or - (at most 64)"
            )
        if isinstance(value, list):
            if len(value) > MAX_ITEMS:
                raise InvalidParameter(f"metadata.{key}", f"at most {MAX_ITEMS} items, got {len(value)}")
            out[key] = [_scalar(f"metadata.{key}[{i}]", v) for i, v in enumerate(value)]
        else:
            out[key] = _scalar(f"metadata.{key}", value)
    return out


def _scalar(field: str, value: Any) -> str | bool | int | float:
    if isinstance(value, bool | int):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise InvalidParameter(field, f"must be a finite number, got {value!r}")
        return value
    if isinstance(value, str):
        if len(value) > MAX_TEXT:
            raise InvalidParameter(field, f"at most {MAX_TEXT} characters, got {len(value)}")
        return value
    if isinstance(value, datetime.date | datetime.time):
        return value.isoformat()
    what = "a table" if isinstance(value, Mapping) else "a nested list" if isinstance(value, list) else repr(value)
    raise InvalidParameter(field, f"must be a string, number, boolean, date or a list of them, got {what}")


def matches(metadata: Mapping[str, Any], text: str | None = None, **fields: Any) -> bool:
    """Whether ``metadata`` has every field as given — equal, or among a list's items; strings
    compared without case — and, with ``text``, holds it (without case) in some value."""
    for key, wanted in fields.items():
        if key not in metadata:
            return False
        value = metadata[key]
        items = value if isinstance(value, list) else [value]
        if not any(_same(item, wanted) for item in items):
            return False
    if text is None:
        return True
    needle = text.casefold()
    values = (v for value in metadata.values() for v in (value if isinstance(value, list) else [value]))
    return any(needle in str(v).casefold() for v in values)


def _same(value: Any, wanted: Any) -> bool:
    if isinstance(value, str) and isinstance(wanted, str):
        return value.casefold() == wanted.casefold()
    if isinstance(value, bool) or isinstance(wanted, bool):  # True is not the integer 1 here
        return value is wanted
    return bool(value == wanted)
