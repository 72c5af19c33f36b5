"""JSON text that strict parsers read: non-finite numbers (NaN, ±inf) become ``null``.

Python's ``json`` writes ``NaN`` and ``Infinity``, which are not JSON: a browser's ``JSON.parse``,
jq, Foxglove and most other readers refuse the whole text. Stored JSON (the ledger's
``metrics_json`` and ``outcome_json``, a run log's structured metadata records) goes through
:func:`dumps`; a metric that is undefined for a run (the current of a rig without one) reads back
as None, which the metrics table shows as NaN.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from typing import Any


def finite(value: Any) -> Any:
    """``value`` with every non-finite float (numpy scalars included) replaced by None."""
    if hasattr(value, "item") and not isinstance(value, (str, bytes)) and getattr(value, "ndim", 0) == 0:
        value = value.item()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite(v) for v in value]
    return value


def dumps(value: Any, *, default: Callable[[Any], Any] | None = None, **options: Any) -> str:
    """:func:`json.dumps` of :func:`finite` ``value``: never a bare NaN or Infinity (``default``
    converts other objects, whose results are made finite too)."""
    convert = None if default is None else (lambda v: finite(default(v)))
    return json.dumps(finite(value), allow_nan=False, default=convert, **options)
