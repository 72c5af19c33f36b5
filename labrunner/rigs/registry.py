"""The registry of rig kinds: ``kind`` → ``"module:Class"``, imported only when chosen.

Like python-can's interface table, a backend's module is imported lazily, so a missing vendor
library never breaks ``import labrunner``. Other packages add kinds through the entry point group
``labrunner.rigs`` (``[project.entry-points."labrunner.rigs"] mykind = "mypkg.rig:MyRig"``) or at
run time with :func:`register_rig`.

A registered class is a :class:`~labrunner.rigs.base.Rig` with four class methods (the
:class:`~labrunner.rigs.sim.SimRig` base provides them from ``PARAMETERS``/``NOISE`` schemas):
``validate_parameters(raw, path) -> dict``, ``validate_noise(raw, path) -> dict``,
``nominal_info(name, description, parameters) -> RigInfo`` and ``from_config(config) -> Rig``.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterable, Mapping
from importlib.metadata import entry_points
from typing import Any

from labrunner.errors import InvalidParameter
from labrunner.rigs.base import Rig
from labrunner.rigs.config import RigConfig, config_from_dict, load_rig_config

ENTRY_POINT_GROUP = "labrunner.rigs"

BUILTIN: dict[str, str] = {
    "dcmotor": "labrunner.rigs.sim.dcmotor:DCMotorTwin",
    "valve": "labrunner.rigs.sim.valve:ValveTwin",
    "plate": "labrunner.rigs.sim.plate:PlateTwin",
    "can": "labrunner.rigs.transports.can:CanRig",
    "serial": "labrunner.rigs.transports.serial:SerialRig",
}

_registered: dict[str, str] = {}


def register_rig(kind: str, target: str) -> None:
    """Register (or replace) ``kind`` → ``"module:Class"``; the module is imported on first use."""
    if not kind or not isinstance(kind, str):
        raise InvalidParameter("kind", f"must be a non-empty string, got {kind!r}")
    if not isinstance(target, str) or target.count(":") != 1:
        raise InvalidParameter("target", f"must be 'module:Class', got {target!r}")
    _registered[kind] = target


def rig_kinds() -> dict[str, str]:
    """Every known kind: built-ins, then entry points, then :func:`register_rig` (later wins)."""
    kinds = dict(BUILTIN)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        kinds[ep.name] = ep.value
    kinds.update(_registered)
    return kinds


def rig_class(kind: str) -> type[Rig]:
    """Import and return the class registered for ``kind``."""
    kinds = rig_kinds()
    if kind not in kinds:
        raise InvalidParameter("kind", f"unknown rig kind {kind!r}; known: {sorted(kinds)}")
    module_name, _, attr = kinds[kind].partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InvalidParameter("kind", f"rig kind {kind!r} -> {kinds[kind]!r} cannot be imported: {exc}") from None
    if not (isinstance(cls, type) and issubclass(cls, Rig)):
        raise InvalidParameter("kind", f"rig kind {kind!r} -> {kinds[kind]!r} is not a Rig class")
    return cls


def load_rig(
    config_or_name: RigConfig | Mapping[str, Any] | str | os.PathLike,
    search: Iterable[str | os.PathLike] | None = (),
) -> Rig:
    """Build a rig from a :class:`RigConfig`, a parsed rig file (dict) or a rig name/path."""
    if isinstance(config_or_name, RigConfig):
        config = config_or_name
    elif isinstance(config_or_name, Mapping):
        config = config_from_dict(config_or_name)
    else:
        config = load_rig_config(config_or_name, search)
    return rig_class(config.kind).from_config(config)
