"""Run-log metadata records as plain text, and back.

Metadata values (MCAP maps strings to strings) are plain text, as a viewer shows them: a string as
it is, a number in decimal (``nan``, ``inf`` included), ``true`` / ``false``; a key whose value is
None is left out; a string that would read as a number or a boolean, or that begins with ``"``,
``{`` or ``[``, is written as a JSON string (``"0042"``). A record holding structured values
(sections, lists: ``config``, ``rig``, ``channels``) is one JSON text under the single key ``json``.
:func:`decode_record` reverses both.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from labrunner import jsontext
from labrunner.errors import InvalidParameter

JSON_KEY = "json"  # the single key of a record stored as one JSON text
_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?|[-+]?(nan|inf|infinity)", re.IGNORECASE)
_INTEGER = re.compile(r"[-+]?\d+")


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store {type(value).__name__} in run metadata")


def _text(value: Any) -> str:
    """One scalar as plain metadata text (see the module's docstring)."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, Path):
        value = str(value)
    if isinstance(value, str):
        if _NUMBER.fullmatch(value) or value in ("true", "false") or value[:1] in ('"', "{", "["):
            return json.dumps(value)
        return value
    raise TypeError(f"cannot store {type(value).__name__} in run metadata")


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (str, int, float, bool, np.generic, Path))


def encode_record(field: str, record: Mapping[str, Any]) -> dict[str, str]:
    """An MCAP metadata map: plain text per key, or one JSON text for structured values."""
    if not isinstance(record, Mapping):
        raise InvalidParameter(f"metadata.{field}", f"must be a mapping, got {type(record).__name__}")
    try:
        if all(_scalar(v) for v in record.values()):
            return {str(k): _text(v) for k, v in record.items() if v is not None}
        return {JSON_KEY: jsontext.dumps(dict(record), default=_jsonable)}  # NaN → null: strict JSON
    except TypeError as exc:
        raise InvalidParameter(f"metadata.{field}", str(exc)) from None


def decode_value(text: str) -> Any:
    """A metadata value back to its type (see the module's docstring)."""
    if text in ("true", "false"):
        return text == "true"
    if _INTEGER.fullmatch(text):
        return int(text)
    if _NUMBER.fullmatch(text):
        return float(text)
    if text[:1] in ('"', "{", "["):
        try:
            return json.loads(text)
        except ValueError:
            return text
    return text


def decode_record(record: Mapping[str, str]) -> dict[str, Any]:
    """A metadata map written by :func:`encode_record` back to Python values."""
    if set(record) == {JSON_KEY} and record[JSON_KEY][:1] == "{":
        try:
            return dict(json.loads(record[JSON_KEY]))
        except ValueError:
            pass
    return {k: decode_value(v) for k, v in record.items()}
