"""The ``[safety]`` section of rig files and campaigns, validated into a :class:`SafetyConfig`.

Kept apart from the monitors (:mod:`labrunner.safety`) so that the rig-file loader
(:mod:`labrunner.rigs.config`) and the engine can both use it: it depends only on the rig's
:class:`~labrunner.rigs.base.RigInfo` (which signals exist) and on the errors, not on the
differentiators the monitors run. Limits come from the rig file's ``[safety]`` section,
overridden key by key by the campaign's ``[safety]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from labrunner.errors import InvalidParameter, check_finite, check_interval, check_positive
from labrunner.rigs.base import RigInfo

_BOUNDS_KEYS = ("output_bounds", "input_bounds")
_SCALAR_KEYS = (
    "max_du_dt",
    "du_dt_alpha",
    "du_dt_beta",
    "du_dt_omega_c",
    "max_duration",
    "motion_output",
    "motion_min_change",
    "motion_min_level",
)


@dataclass(frozen=True)
class SafetyConfig:
    """Validated safety limits of one run (SI units of the rig's signals).

    ``max_du_dt`` [input unit / s] (``None`` disables the rate monitor) is estimated with an
    algebraic differentiator of parameters ``du_dt_*``. ``output_bounds`` / ``input_bounds`` map a
    signal name to its allowed closed interval; an output bound may also name a signal the rig
    derives from its outputs (``RigInfo.derived``: the plate's air gaps h1..h4, paper 2 eq. (4)).
    ``max_duration`` [s] aborts longer runs.
    ``motion_*`` define "the load moved": the output ``motion_output`` changed by more than
    ``motion_min_change`` from its first value, or rose above ``motion_min_level``.
    """

    max_du_dt: float | None = None
    du_dt_alpha: float = 6.0
    du_dt_beta: float = 6.0
    du_dt_omega_c: float = 200.0
    output_bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    input_bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    max_duration: float | None = None
    motion_output: str | None = None
    motion_min_change: float | None = None
    motion_min_level: float | None = None

    @classmethod
    def from_sections(cls, rig_info: RigInfo, *sections: Mapping[str, object], prefix: str = "safety") -> SafetyConfig:
        """Merge ``sections`` (rig file first, campaign last) and validate every key."""
        merged: dict[str, object] = {}
        for section in sections:
            for key, value in (section or {}).items():
                if key in _BOUNDS_KEYS and isinstance(value, Mapping):
                    merged[key] = {**dict(merged.get(key, {})), **dict(value)}
                else:
                    merged[key] = value
        unknown = sorted(set(merged) - set(_BOUNDS_KEYS) - set(_SCALAR_KEYS))
        if unknown:
            allowed = ", ".join(_SCALAR_KEYS + _BOUNDS_KEYS)
            raise InvalidParameter(f"{prefix}.{unknown[0]}", f"unknown key; allowed: {allowed}")
        kw: dict[str, object] = {}
        for key in ("max_du_dt", "max_duration", "motion_min_change", "du_dt_alpha", "du_dt_beta", "du_dt_omega_c"):
            if merged.get(key) is not None:
                kw[key] = check_positive(f"{prefix}.{key}", merged[key])
        if merged.get("motion_min_level") is not None:
            kw["motion_min_level"] = check_finite(f"{prefix}.motion_min_level", merged["motion_min_level"])
        outputs = [s.name for s in rig_info.outputs]
        names = {
            "output_bounds": outputs + [d.name for d in rig_info.derived],
            "input_bounds": [s.name for s in rig_info.inputs],
        }
        for key in _BOUNDS_KEYS:
            bounds = {}
            for name, pair in dict(merged.get(key, {})).items():
                path = f"{prefix}.{key}.{name}"
                if name not in names[key]:
                    raise InvalidParameter(path, f"unknown signal; rig {rig_info.name!r} has {names[key]}")
                bounds[name] = check_interval(path, pair)
            kw[key] = bounds
        if merged.get("motion_output") is not None:
            out = str(merged["motion_output"])
            if out not in outputs:
                raise InvalidParameter(f"{prefix}.motion_output", f"must be one of {outputs}, got {out!r}")
            kw["motion_output"] = out
        return cls(**kw)
