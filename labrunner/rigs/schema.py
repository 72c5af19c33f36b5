"""Parameter schemas of rig kinds: :class:`Param` and the validation of a section against one.

The bottom of :mod:`labrunner.rigs`: it imports nothing of the package but the errors, so the
rig contract (:mod:`labrunner.rigs.base`), the registry and the rig-file loader
(:mod:`labrunner.rigs.config`) all build on it without a cycle. A rig kind declares its rig
file's ``[parameters]`` and ``[noise]`` sections as ``{key: Param}``; :func:`validate_section`
checks a section against that (unknown keys rejected, defaults filled in) and
:meth:`Param.check_array` checks per-run overrides.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from labrunner.errors import InvalidParameter, check_finite


@dataclass(frozen=True)
class Param:
    """Schema of one rig parameter: default, unit, why it has this value, allowed range.

    The type is the default's type (``float``, ``int``, ``str``, ``bool``). Numbers must lie in
    ``[lo, hi]`` (``lo_open``: ``lo`` itself excluded); strings in ``choices`` when given.
    """

    default: float | int | str | bool
    unit: str
    doc: str
    lo: float = -np.inf
    hi: float = np.inf
    lo_open: bool = False
    choices: tuple[str, ...] = ()

    @property
    def numeric(self) -> bool:
        return isinstance(self.default, (int, float)) and not isinstance(self.default, bool)

    def _range(self) -> str:
        left = "(" if self.lo_open else "["
        return f"in {left}{self.lo:g}, {self.hi:g}]"

    def check(self, field_name: str, value: Any) -> float | int | str | bool:
        """Validate one value; return it with the schema's type."""
        if isinstance(self.default, bool):
            if not isinstance(value, bool):
                raise InvalidParameter(field_name, f"must be true or false, got {value!r}")
            return value
        if isinstance(self.default, str):
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                allowed = f"one of {list(self.choices)}" if self.choices else "a string"
                raise InvalidParameter(field_name, f"must be {allowed}, got {value!r}")
            return value
        if isinstance(value, bool):
            raise InvalidParameter(field_name, f"must be a number, got {value!r}")
        v = check_finite(field_name, value)
        if isinstance(self.default, int) and v != int(v):
            raise InvalidParameter(field_name, f"must be an integer, got {value!r}")
        self._check_range(field_name, np.array([v]))
        return int(v) if isinstance(self.default, int) else v

    def check_array(
        self, field_name: str, values: Any, batch: int, nominal: np.ndarray | float | None = None
    ) -> np.ndarray:
        """Validate per-run values (scalar or (B,)); return a (B,) float array.

        With ``nominal``, NaN entries mean "this run keeps the nominal value" (the engine passes NaN
        for runs whose point does not set the parameter). Integer parameters need integer values.
        """
        if not self.numeric:
            raise InvalidParameter(field_name, "is not a numeric parameter and cannot vary per run")
        arr = np.asarray(values, dtype=float)
        if arr.ndim > 1 or (arr.ndim == 1 and arr.size != batch):
            raise InvalidParameter(field_name, f"needs a scalar or one value per run ({batch}), got shape {arr.shape}")
        if nominal is not None:
            arr = np.where(np.isnan(arr), nominal, arr)
        if not np.all(np.isfinite(arr)):
            raise InvalidParameter(field_name, f"must be finite, got {arr[~np.isfinite(arr)][0]!r}")
        if isinstance(self.default, int) and np.any(arr != np.round(arr)):
            raise InvalidParameter(field_name, f"must be an integer, got {arr[arr != np.round(arr)][0]:g}")
        self._check_range(field_name, arr.reshape(-1))
        return np.broadcast_to(arr, (batch,)).astype(float)

    def _check_range(self, field_name: str, v: np.ndarray) -> None:
        bad = (v <= self.lo) if self.lo_open else (v < self.lo)
        bad |= v > self.hi
        if bad.any():
            x = v[bad][0]
            if np.isinf(self.hi):
                msg = f"must be {'>' if self.lo_open else '>='} {self.lo:g}, got {x:g}"
            else:
                msg = f"must be {self._range()}, got {x:g}"
            raise InvalidParameter(field_name, msg)


Schema = Mapping[str, Param]


def as_table(raw: Any, path: str) -> dict[str, Any]:
    """A TOML table (None: empty) as a dict; anything else is an error naming ``path``."""
    if raw is None:
        return {}
    if not isinstance(raw, Mapping):
        raise InvalidParameter(path, f"must be a table, got {raw!r}")
    return dict(raw)


def validate_section(schema: Schema, raw: Mapping[str, Any], path: str) -> dict[str, Any]:
    """Check ``raw`` against ``schema`` (unknown keys rejected) and fill in the defaults."""
    raw = as_table(raw, path)
    unknown = sorted(set(raw) - set(schema))
    if unknown:
        allowed = ", ".join(schema) or "no keys"
        raise InvalidParameter(f"{path}.{unknown[0]}", f"unknown key; allowed: {allowed}")
    return {k: p.check(f"{path}.{k}", raw[k]) if k in raw else p.default for k, p in schema.items()}
