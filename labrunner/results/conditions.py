"""What :meth:`~labrunner.results.campaign.CampaignResults.select` accepts as a condition, and how
each matches a column: a value, several values (a list, tuple, set, range, numpy array or any
other iterable), a closed range (``slice``), a grid value nearest to a number (:func:`near`), or
a callable returning a mask. Anything that would match silently wrong — a NaN, a reversed range, a
slice's step, a number on no grid value — is refused in one line naming the column."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from labrunner.errors import InvalidParameter

#: Relative tolerance of an exact match of floats (grid values are computed, e.g. by ``logspace``).
RTOL = 1e-9


@dataclass(frozen=True)
class Near:
    """Match the column's value nearest to ``value`` (all its rows), as xarray's
    ``sel(method="nearest")``; with ``tolerance``, only if it is within that distance."""

    value: float
    tolerance: float | None = None


def near(value: float, tolerance: float | None = None) -> Near:
    """A :meth:`select` condition: the grid value nearest ``value`` (within ``tolerance`` if given),
    e.g. ``select(k_p=near(2.154))`` for the 2.1544… that the report prints as 2.154."""
    v = _number("value", value)
    if math.isinf(v):
        raise InvalidParameter("near", f"value must be finite, got {value!r}")
    if tolerance is not None:
        tol = _number("tolerance", tolerance)
        if not tol >= 0 or math.isinf(tol):
            raise InvalidParameter("near", f"tolerance must be a finite number >= 0, got {tolerance!r}")
        return Near(v, tol)
    return Near(v)


def _number(field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InvalidParameter("near", f"{field} must be a number, got {value!r}")
    v = float(value)
    if math.isnan(v):
        raise InvalidParameter("near", f"{field} must be a number, got NaN")
    return v


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _numbers(column: pd.Series) -> np.ndarray:
    return pd.to_numeric(column, errors="coerce").to_numpy(dtype=float)


def _shown(value: float) -> str:
    """Every digit of ``value`` (the shortest text that reads back as it): a closest value must be
    told apart from the one asked for."""
    return repr(float(value))


def _closest(name: str, numbers: np.ndarray, value: float) -> float:
    """The column's value nearest ``value``, or a refusal when the column holds no numbers."""
    finite = numbers[np.isfinite(numbers)]
    if not len(finite):
        raise InvalidParameter(name, f"holds no numbers to match {_shown(value)} against")
    return float(finite[np.argmin(np.abs(finite - value))])


def mask(name: str, column: pd.Series, wanted: Any, *, grid: bool) -> np.ndarray:
    """Boolean mask of ``column`` (named ``name``) against one condition; ``grid``: the column is
    a parameter, where a number that is on no grid value is a mistake to report, not 0 rows."""
    if callable(wanted) and not isinstance(wanted, Near):
        return _called(name, column, wanted)
    if isinstance(wanted, Near):
        return _near(name, column, wanted)
    if isinstance(wanted, slice):
        return _range(name, column, wanted)
    if isinstance(wanted, np.ndarray) and wanted.ndim == 0:
        wanted = wanted.item()
    if isinstance(wanted, Mapping):
        raise InvalidParameter(
            name, f"a mapping is no condition: give a value, a list, a slice or near(); got {wanted!r}"
        )
    if isinstance(wanted, Iterable) and not isinstance(wanted, (str, bytes)):
        options = list(wanted.tolist() if isinstance(wanted, np.ndarray) else wanted)  # generators, ranges too
        if not options:
            raise InvalidParameter(name, "an empty list of values matches nothing")
    else:
        options = [wanted]
    out = np.zeros(len(column), dtype=bool)
    for option in options:
        out |= _equal(name, column, option, grid=grid)
    return out


def _called(name: str, column: pd.Series, wanted: Callable[[pd.Series], Any]) -> np.ndarray:
    out = np.asarray(wanted(column))
    if out.shape != (len(column),) or out.dtype != bool:
        raise InvalidParameter(
            name, f"a callable must return one boolean per row ({len(column)}), got {out.dtype} {out.shape}"
        )
    return out


def _near(name: str, column: pd.Series, wanted: Near) -> np.ndarray:
    numbers = _numbers(column)
    closest = _closest(name, numbers, wanted.value)
    if wanted.tolerance is not None and abs(closest - wanted.value) > wanted.tolerance:
        raise InvalidParameter(
            name,
            f"no grid value within {_shown(wanted.tolerance)} of {_shown(wanted.value)}; closest {_shown(closest)}",
        )
    return np.isclose(numbers, closest, rtol=RTOL, atol=0.0)


def _range(name: str, column: pd.Series, wanted: slice) -> np.ndarray:
    if wanted.step is not None:
        raise InvalidParameter(
            name,
            f"a slice's step is not supported ({wanted!r}): give the values as a list, or a callable",
        )
    ends = []
    for end, default in ((wanted.start, -math.inf), (wanted.stop, math.inf)):
        if end is None:
            ends.append(default)
            continue
        if not _is_number(end) or math.isnan(float(end)):
            raise InvalidParameter(name, f"a slice's ends must be numbers or None, got {wanted!r}")
        ends.append(float(end))
    lo, hi = ends
    if lo > hi:
        raise InvalidParameter(name, f"the range is reversed ({wanted!r}): give slice(low, high)")
    values = _numbers(column)
    return (values >= lo) & (values <= hi)


def _equal(name: str, column: pd.Series, value: Any, *, grid: bool) -> np.ndarray:
    if not _is_number(value):
        if value is None:
            raise InvalidParameter(
                name, "None equals no value: select missing values with a callable (lambda c: c.isna())"
            )
        return (column == value).fillna(False).to_numpy(dtype=bool)
    v = float(value)
    if math.isnan(v):
        raise InvalidParameter(name, "NaN equals no value: select missing values with a callable (lambda c: c.isna())")
    numbers = _numbers(column)
    hit = numbers == v if math.isinf(v) else np.isclose(numbers, v, rtol=RTOL, atol=0.0)
    if grid and not hit.any():
        closest = _closest(name, numbers, v)
        raise InvalidParameter(
            name, f"no grid value near {_shown(v)}; closest {_shown(closest)} (select it with near({_shown(v)}))"
        )
    return hit
