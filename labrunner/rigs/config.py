"""Rig description files (``rigs/<name>.toml``): finding, loading and validating them into a frozen
:class:`~labrunner.rigs.base.RigConfig`.

A rig file has the sections ``[rig]`` (``kind``, ``name``, ``description``), ``[parameters]``,
``[limits]``, ``[noise]``, ``[faults]`` and ``[safety]`` (format: ``docs/rigs.md``). Every key is
validated; an unknown key or a bad value raises :class:`~labrunner.errors.InvalidParameter`
whose field is ``"<file>: <section>.<key>"``, e.g.
``InvalidParameter("rigs/dcmotor-sim.toml: parameters.a", "must be > 0, got -1")``.

The rig kind decides what ``[parameters]`` and ``[noise]`` may hold: its class (looked up in
:mod:`labrunner.rigs.kinds`) declares them as :class:`~labrunner.rigs.schema.Param` schemas and
validates them (the :class:`~labrunner.rigs.base.Rig` contract). ``[safety]`` is validated by
:class:`labrunner.safety_config.SafetyConfig`. ``Param``, ``RigConfig`` and ``validate_section``
are re-exported here for the modules that describe rig files.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from labrunner import inputfile
from labrunner.errors import InvalidParameter, check_finite, check_interval
from labrunner.rigs.base import Faults, RigConfig, RigInfo, Signal
from labrunner.rigs.kinds import rig_class
from labrunner.rigs.schema import Param, as_table, validate_section
from labrunner.safety_config import SafetyConfig

__all__ = [
    "Param",
    "RigConfig",
    "apply_limits",
    "config_from_dict",
    "default_search",
    "load_rig_config",
    "parse_faults",
    "resolve_rig_file",
    "rig_info",
    "search_path",
    "validate_section",
]

SECTIONS = ("rig", "parameters", "limits", "noise", "faults", "safety")
_RIG_KEYS = ("kind", "name", "description")
_FAULT_KEYS = ("t_start", "actuator_offset", "actuator_gain", "sensor_step")


def apply_limits(info: RigInfo, raw: Mapping[str, Any], path: str = "limits") -> tuple[RigInfo, dict[str, Any]]:
    """Narrow ``info`` by a ``[limits]`` table; return the new info and the validated table.

    Keys: a signal name → ``[lo, hi]`` inside the signal's physical range; ``fs = [lo, hi]`` inside
    the rig's allowed rates [Hz]; ``fs_default`` inside the (narrowed) rates.
    """
    raw = as_table(raw, path)
    signals = {s.name: s for s in info.inputs + info.outputs}
    out: dict[str, Any] = {}
    narrowed: dict[str, Signal] = {}
    fs_lo, fs_hi = info.fs_range
    for key, value in raw.items():
        kpath = f"{path}.{key}"
        if key == "fs":
            lo, hi = check_interval(kpath, value)
            if lo < fs_lo or hi > fs_hi:
                raise InvalidParameter(kpath, f"must lie in [{fs_lo:g}, {fs_hi:g}] Hz, got [{lo:g}, {hi:g}]")
            out[key] = (lo, hi)
        elif key == "fs_default":
            out[key] = check_finite(kpath, value)
        elif key in signals:
            s = signals[key]
            lo, hi = check_interval(kpath, value)
            if lo < s.lo or hi > s.hi:
                raise InvalidParameter(kpath, f"must lie in [{s.lo:g}, {s.hi:g}] {s.unit}, got [{lo:g}, {hi:g}]")
            out[key] = (lo, hi)
            narrowed[key] = replace(s, lo=lo, hi=hi)
        else:
            allowed = ", ".join([*signals, "fs", "fs_default"])
            raise InvalidParameter(kpath, f"unknown key; allowed: {allowed}")
    fs_range = out.get("fs", info.fs_range)
    fs_default = out.get(
        "fs_default", info.fs_default if fs_range[0] <= info.fs_default <= fs_range[1] else fs_range[0]
    )
    if not fs_range[0] <= fs_default <= fs_range[1]:
        raise InvalidParameter(
            f"{path}.fs_default", f"must lie in [{fs_range[0]:g}, {fs_range[1]:g}] Hz, got {fs_default:g}"
        )
    safe = tuple(
        float(np.clip(v, narrowed.get(s.name, s).lo, narrowed.get(s.name, s).hi))
        for v, s in zip(info.safe_input, info.inputs)
    )
    info = replace(
        info,
        inputs=tuple(narrowed.get(s.name, s) for s in info.inputs),
        outputs=tuple(narrowed.get(s.name, s) for s in info.outputs),
        fs_range=(float(fs_range[0]), float(fs_range[1])),
        fs_default=float(fs_default),
        safe_input=safe,
    )
    return info, out


def parse_faults(raw: Mapping[str, Any], info: RigInfo, path: str = "faults") -> Faults:
    """Map a ``[faults]`` table onto :class:`~labrunner.rigs.base.Faults` (paper 2 Sec. 4.4).

    ``t_start`` [s] ≥ 0; ``actuator_offset``, ``actuator_gain`` (> −1) per input and
    ``sensor_step`` per output, each a number (all channels) or a list with one value per channel.
    """
    raw = as_table(raw, path)
    unknown = sorted(set(raw) - set(_FAULT_KEYS))
    if unknown:
        raise InvalidParameter(f"{path}.{unknown[0]}", f"unknown key; allowed: {', '.join(_FAULT_KEYS)}")
    if not raw:
        return Faults()
    if "t_start" not in raw:
        raise InvalidParameter(f"{path}.t_start", "is required when faults are given")
    t_start = check_finite(f"{path}.t_start", raw["t_start"])
    if t_start < 0:
        raise InvalidParameter(f"{path}.t_start", f"must be >= 0, got {t_start:g}")
    n_in, n_out = len(info.inputs), len(info.outputs)

    def channels(key: str, n: int, lo: float = -np.inf) -> tuple[float, ...]:
        value = raw.get(key, 0.0)
        values = value if isinstance(value, (list, tuple)) else [value]
        if len(values) not in (1, n):
            need = "1 value" if n == 1 else f"1 or {n} values"
            raise InvalidParameter(f"{path}.{key}", f"needs {need}, got {len(values)}")
        out = tuple(check_finite(f"{path}.{key}", v) for v in values)
        if any(v <= lo for v in out):
            raise InvalidParameter(f"{path}.{key}", f"must be > {lo:g}, got {min(out):g}")
        return out

    return Faults(
        t_start=t_start,
        actuator_offset=channels("actuator_offset", n_in),
        actuator_gain=channels("actuator_gain", n_in, lo=-1.0),
        sensor_step=channels("sensor_step", n_out),
    )


def _display(path: Path) -> str:
    rel = os.path.relpath(path)
    return rel if not rel.startswith("..") else str(path)


def search_path(search: Iterable[str | os.PathLike] = ()) -> tuple[Path, ...]:
    """Where rig names are looked up: the caller's ``search`` directories (e.g. the campaign
    project's ``rigs/``), then ``./rigs``, then this checkout's ``rigs/``; duplicates dropped."""
    dirs = [Path(d) for d in search] + [Path.cwd() / "rigs", Path(__file__).resolve().parents[2] / "rigs"]
    unique: list[Path] = []
    for d in dirs:
        if d.resolve() not in [u.resolve() for u in unique]:
            unique.append(d)
    return tuple(unique)


def default_search(project_dir: str | os.PathLike | None = None) -> tuple[Path, ...]:
    """The search path for a campaign in ``project_dir``: ``<project_dir>/rigs``, ``./rigs``, the checkout's."""
    return search_path(() if project_dir is None else (Path(project_dir) / "rigs",))


def resolve_rig_file(name_or_path: str | os.PathLike, search: Iterable[str | os.PathLike] | None = ()) -> Path:
    """A path (contains a separator or ends in ``.toml``) as is; a name as ``<dir>/<name>.toml``
    in the first directory of :func:`search_path` that has it."""
    text = str(name_or_path)
    if os.sep in text or "/" in text or text.endswith(".toml"):
        path = Path(text)
        if not path.is_file():
            raise InvalidParameter("rig", f"no rig file {text!r}")
        return path
    dirs = search_path(search or ())
    for d in dirs:
        if (d / f"{text}.toml").is_file():
            return d / f"{text}.toml"
    raise InvalidParameter("rig", f"no rig file {text}.toml in {[str(d) for d in dirs]}")


#: The link keys of a real rig's ``[parameters]`` a command line may set instead of the file
#: (``check-rig``, ``conform``: ``--port /dev/pts/3``; ``--interface udp_multicast --channel …``).
LINK_KEYS = {"serial": ("port",), "can": ("interface", "channel")}


def load_rig_config(
    name_or_path: str | os.PathLike,
    search: Iterable[str | os.PathLike] | None = (),
    *,
    link: Mapping[str, str | None] | None = None,
) -> RigConfig:
    """Find, parse and validate a rig file (see :func:`resolve_rig_file` for the lookup); ``link``
    (:data:`LINK_KEYS`; None values ignored) replaces the file's port or CAN interface and channel,
    validated as if the file said so (the emulator's pty without editing a copy of the file)."""
    path = resolve_rig_file(name_or_path, search)
    source = _display(path)
    data = inputfile.loads_toml(inputfile.read_text(path, source, "rig file"), source, f"{source}: ")
    given = {k: v for k, v in (link or {}).items() if v is not None}
    if given:
        data = _with_link(data, given, source)
    return config_from_dict(data, source=source, default_name=path.stem)


def _with_link(data: Mapping[str, Any], link: Mapping[str, str], source: str) -> dict[str, Any]:
    """``data`` with ``link`` set in its ``[parameters]``; a key its kind has no use for is refused."""
    rig = data.get("rig")
    kind = rig.get("kind") if isinstance(rig, Mapping) else None
    for key in link:
        if key not in LINK_KEYS.get(kind, ()):  # type: ignore[arg-type]
            takes = [k for k, keys in LINK_KEYS.items() if key in keys]
            raise InvalidParameter(f"--{key}", f"applies to a {' or '.join(takes)} rig; {source} is a {kind!r} rig")
    parameters = data.get("parameters")
    return {**data, "parameters": {**(parameters if isinstance(parameters, Mapping) else {}), **link}}


def config_from_dict(data: Mapping[str, Any], *, source: str = "<dict>", default_name: str | None = None) -> RigConfig:
    """Validate a parsed rig file (the same checks as :func:`load_rig_config`)."""
    pre = f"{source}: "
    data = as_table(data, source)
    unknown = sorted(set(data) - set(SECTIONS))
    if unknown:
        raise InvalidParameter(f"{pre}{unknown[0]}", f"unknown section; allowed: {', '.join(SECTIONS)}")
    rig = as_table(data.get("rig"), f"{pre}rig")
    bad = sorted(set(rig) - set(_RIG_KEYS))
    if bad:
        raise InvalidParameter(f"{pre}rig.{bad[0]}", f"unknown key; allowed: {', '.join(_RIG_KEYS)}")
    if "kind" not in rig:
        raise InvalidParameter(f"{pre}rig.kind", "is required")
    for key in _RIG_KEYS:
        if key in rig and not isinstance(rig[key], str):
            raise InvalidParameter(f"{pre}rig.{key}", f"must be a string, got {rig[key]!r}")
    kind = rig["kind"]
    try:
        cls = rig_class(kind)
    except InvalidParameter as exc:
        raise InvalidParameter(f"{pre}rig.kind", exc.message) from None
    name = rig.get("name", default_name or kind)
    description = rig.get("description", "")
    parameters = cls.validate_parameters(as_table(data.get("parameters"), f"{pre}parameters"), f"{pre}parameters")
    noise = cls.validate_noise(as_table(data.get("noise"), f"{pre}noise"), f"{pre}noise")
    info = cls.nominal_info(name, description, parameters)
    info, limits = apply_limits(info, data.get("limits"), f"{pre}limits")
    faults = parse_faults(data.get("faults"), info, f"{pre}faults")
    safety = as_table(data.get("safety"), f"{pre}safety")
    SafetyConfig.from_sections(info, safety, prefix=f"{pre}safety")
    return RigConfig(name, kind, description, parameters, limits, noise, faults, safety, source, info)


def rig_info(config: RigConfig) -> RigInfo:
    """The RigInfo a rig built from ``config`` has (nominal signals narrowed by ``[limits]``)."""
    if config.info is not None:
        return config.info
    info = rig_class(config.kind).nominal_info(config.name, config.description, config.parameters)
    return apply_limits(info, dict(config.limits))[0]
