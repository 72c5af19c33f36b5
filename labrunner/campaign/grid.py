"""Grid axes of a campaign, their expansion into points, and stable point ids.

Axis forms (``[grid]`` of a campaign file, keys are dotted keys of the file):

- ``{ values = [v1, v2, ...] }`` — the listed values (numbers, strings, booleans or lists);
- ``{ linspace = [a, b], num = n }`` — n evenly spaced values from a to b;
- ``{ log10 = [a, b], num = n }`` — n values 10^a … 10^b, evenly spaced in log10 (a, b are
  exponents, as the log-scaled parameter sweeps of thesis Sec. 3.5 and paper 1 Fig. 5);
- ``zip = [["k1", "k2"], ...]`` — the named axes vary together (equal lengths) instead of
  spanning a Cartesian product.

Points are the Cartesian product of the axis groups in file order (first axis slowest). A point's
id is a hash of the campaign identity and the canonical JSON of its parameter values, so the same
point keeps its id across runs, resumes and machines.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from labrunner.errors import InvalidParameter, check_finite, check_interval

MAX_POINTS = 1_000_000  # a campaign beyond this is a typo or should be split (issue 26: 10^6 runs)
_FORMS = ("values", "linspace", "log10")
_MAX_EXPONENT = 300.0


@dataclass(frozen=True)
class Axis:
    """One grid axis: a dotted key of the campaign file, its values in order, and its form
    (``values``, ``linspace`` or ``log10``: maps draw a log10 axis on a log scale)."""

    key: str
    values: tuple[Any, ...]
    form: str = "values"


@dataclass(frozen=True)
class Grid:
    """Axis groups; the grid is the Cartesian product of the groups, each group zips its axes."""

    groups: tuple[tuple[Axis, ...], ...] = ()

    @property
    def size(self) -> int:
        return math.prod(len(g[0].values) for g in self.groups) if self.groups else 1

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(a.key for g in self.groups for a in g)

    def points(self) -> Iterator[dict[str, Any]]:
        """Parameter dicts (dotted key → value) in grid order; one empty dict for an empty grid."""
        for combo in itertools.product(*(range(len(g[0].values)) for g in self.groups)):
            params: dict[str, Any] = {}
            for group, i in zip(self.groups, combo):
                for axis in group:
                    params[axis.key] = axis.values[i]
            yield params


def canonical_json(value: Any) -> str:
    """Deterministic JSON (sorted keys, no spaces, no NaN): the basis of ids and checksums."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False, ensure_ascii=False)


def point_id(identity: str, parameters: Mapping[str, Any]) -> str:
    """Stable id of a point: 16 hex digits of SHA-256(identity ‖ canonical JSON of its parameters)."""
    digest = hashlib.sha256(f"{identity}\x00{canonical_json(dict(parameters))}".encode())
    return digest.hexdigest()[:16]


def _flatten(table: Mapping[str, Any], prefix: str) -> Iterator[tuple[str, Any]]:
    """(dotted key, axis spec): TOML turns an unquoted ``controller.k_p = {...}`` into nested tables."""
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, Mapping) and not any(f in value for f in _FORMS) and value:
            yield from _flatten(value, path)
        else:
            yield path, value


def _scalar_value(field: str, v: Any) -> Any:
    if isinstance(v, bool) or isinstance(v, str):
        return v
    if isinstance(v, int):
        return v
    if isinstance(v, float):
        return check_finite(field, v)
    if isinstance(v, list) and v:
        return [_scalar_value(field, x) for x in v]
    raise InvalidParameter(field, f"values must be numbers, strings, booleans or non-empty lists, got {v!r}")


def _count(field: str, spec: Mapping[str, Any]) -> int:
    num = spec.get("num")
    if num is None:
        raise InvalidParameter(f"{field}.num", "is required with linspace/log10 (number of values, >= 1)")
    if isinstance(num, bool) or not isinstance(num, int) or not 1 <= num <= MAX_POINTS:
        raise InvalidParameter(
            f"{field}.num", f"must be an integer in 1..{MAX_POINTS:,} (the grid's point limit), got {num!r}"
        )
    return num


def parse_axis(field: str, key: str, spec: Any) -> Axis:
    """One axis from its table; ``field`` is its key path for errors (``grid."controller.k_p"``)."""
    if not isinstance(spec, Mapping):
        raise InvalidParameter(field, f"must be a table with one of {', '.join(_FORMS)}, got {spec!r}")
    forms = [f for f in _FORMS if f in spec]
    unknown = sorted(set(spec) - set(_FORMS) - {"num"})
    if unknown:
        raise InvalidParameter(f"{field}.{unknown[0]}", f"unknown axis key (allowed: {', '.join(_FORMS)}, num)")
    if len(forms) != 1:
        raise InvalidParameter(field, f"needs exactly one of {', '.join(_FORMS)}, got {forms or 'none'}")
    form = forms[0]
    if form == "values":
        values = spec["values"]
        if "num" in spec:
            raise InvalidParameter(f"{field}.num", "is only allowed with linspace/log10")
        if not isinstance(values, list) or not values:
            raise InvalidParameter(f"{field}.values", f"must be a non-empty list, got {values!r}")
        return Axis(key, tuple(_scalar_value(f"{field}.values", v) for v in values))
    a, b = check_interval(f"{field}.{form}", spec[form], what="[start, stop] (two numbers)", empty=True)
    num = _count(field, spec)
    if form == "log10" and max(abs(a), abs(b)) > _MAX_EXPONENT:
        raise InvalidParameter(f"{field}.log10", f"exponents must be within ±{_MAX_EXPONENT:g}, got [{a:g}, {b:g}]")
    lin = np.linspace(a, b, num)
    values = 10.0**lin if form == "log10" else lin
    return Axis(key, tuple(float(v) for v in values), form)


def _zip_groups(spec: Any) -> list[list[str]]:
    if not isinstance(spec, list) or not spec:
        raise InvalidParameter("grid.zip", f"must be a list of axis keys or of lists of axis keys, got {spec!r}")
    groups = [spec] if all(isinstance(s, str) for s in spec) else spec
    for g in groups:
        if not isinstance(g, list) or len(g) < 2 or not all(isinstance(k, str) for k in g):
            raise InvalidParameter("grid.zip", f"each group must list at least two axis keys, got {g!r}")
    return groups


def parse_grid(
    table: Mapping[str, Any],
    check_key: Callable[[str, str], None],
    max_points: int = MAX_POINTS,
) -> Grid:
    """Validate ``[grid]``; ``check_key(field, key)`` refuses keys the campaign cannot set."""
    if not isinstance(table, Mapping):
        raise InvalidParameter("grid", f"must be a table of axes, got {table!r}")
    entries: dict[str, Any] = {}
    for key, spec in _flatten({k: v for k, v in table.items() if k != "zip"}, ""):
        if key in entries:  # "a.b" = … and a.b = … (or [grid.a] b = …) name the same axis
            raise InvalidParameter(f'grid."{key}"', "is given twice (quoted and dotted spellings name the same key)")
        entries[key] = spec
    if not entries:
        raise InvalidParameter("grid", "is empty; add an axis or remove [grid] for a single run")
    axes: dict[str, Axis] = {}
    for key, spec in entries.items():
        field = f'grid."{key}"'
        check_key(field, key)
        axes[key] = parse_axis(field, key, spec)
    grouped: dict[str, int] = {}
    zipped = _zip_groups(table["zip"]) if "zip" in table else []
    for gi, group in enumerate(zipped):
        for key in group:
            if key not in axes:
                raise InvalidParameter("grid.zip", f"{key!r} is not an axis of [grid] (axes: {', '.join(axes)})")
            if key in grouped:
                raise InvalidParameter("grid.zip", f"{key!r} appears in more than one zip group")
            grouped[key] = gi
        lengths = {len(axes[k].values) for k in group}
        if len(lengths) > 1:
            raise InvalidParameter("grid.zip", f"zipped axes {group} need equal lengths, got {sorted(lengths)}")
    for key, axis in axes.items():
        if key not in grouped:
            _check_distinct(f'grid."{key}"', axis.values)
    groups: list[tuple[Axis, ...]] = []
    placed: set[int] = set()
    for key, axis in axes.items():
        if key not in grouped:
            groups.append((axis,))
        elif grouped[key] not in placed:
            placed.add(grouped[key])
            groups.append(tuple(axes[k] for k in zipped[grouped[key]]))
    size = math.prod(len(g[0].values) for g in groups)
    if size > max_points:
        raise InvalidParameter(
            "grid", f"has {size:,} points, more than the limit of {max_points:,}; split the campaign"
        )
    return Grid(tuple(groups))


def _same(value: Any) -> Any:
    """A form in which numerically equal values agree (50 and 50.0), other values stay apart."""
    if isinstance(value, bool) or isinstance(value, str):
        return (type(value).__name__, value)
    if isinstance(value, (int, float)):
        return ("number", float(value))
    if isinstance(value, (list, tuple)):
        return ("list", tuple(_same(v) for v in value))
    if isinstance(value, Mapping):
        return ("table", tuple(sorted((k, _same(v)) for k, v in value.items())))
    return ("other", repr(value))


def _check_distinct(field: str, values: Sequence[Any]) -> None:
    seen: dict[Any, Any] = {}
    for v in values:
        key = _same(v)
        if key in seen:
            raise InvalidParameter(
                field, f"has the value {v!r} twice ({seen[key]!r} and {v!r} are equal); each point runs once"
            )
        seen[key] = v


def check_unique(ids: Sequence[str], params: Sequence[Mapping[str, Any]]) -> None:
    """Refuse a grid in which two points coincide (equal values, e.g. 50 and 50.0, count as one)."""
    seen: set[Any] = set()
    for i, pid in enumerate(ids):
        key = _same(dict(params[i]))
        if pid in seen or key in seen:
            raise InvalidParameter("grid", f"point {canonical_json(dict(params[i]))} appears more than once")
        seen.add(pid)
        seen.add(key)
