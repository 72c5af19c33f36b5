"""The table of rig kinds: ``kind`` → ``"module:Class"``, imported only when chosen.

Like python-can's interface table, a backend's module is imported lazily, so a missing vendor
library never breaks ``import labrunner``. Other packages add kinds through the entry point group
``labrunner.rigs`` (``[project.entry-points."labrunner.rigs"] mykind = "mypkg.rig:MyRig"``) or at
run time with :func:`register_rig`. A class is checked against the :class:`~labrunner.rigs.base.Rig`
contract when it is registered as a class, and when a ``"module:Class"`` target is first imported.

This module sits under the rig-file loader (:mod:`labrunner.rigs.config`), which looks kinds up
here; :mod:`labrunner.rigs.registry` is the public face of both.
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Mapping
from importlib.metadata import entry_points

from labrunner.errors import InvalidParameter
from labrunner.rigs.base import Rig

ENTRY_POINT_GROUP = "labrunner.rigs"

BUILTIN: dict[str, str] = {
    "dcmotor": "labrunner.rigs.sim.dcmotor:DCMotorTwin",
    "valve": "labrunner.rigs.sim.valve:ValveTwin",
    "plate": "labrunner.rigs.sim.plate:PlateTwin",
    "can": "labrunner.rigs.transports.can:CanRig",
    "serial": "labrunner.rigs.transports.serial:SerialRig",
}

_registered: dict[str, str | type[Rig]] = {}


def register_rig(kind: str, target: str | type[Rig]) -> None:
    """Register (or replace) ``kind`` → ``"module:Class"`` (imported on first use) or a Rig class
    (checked against the contract now)."""
    if not kind or not isinstance(kind, str):
        raise InvalidParameter("kind", f"must be a non-empty string, got {kind!r}")
    if isinstance(target, type):
        check_contract(kind, target, target.__qualname__)
    elif not isinstance(target, str) or target.count(":") != 1:
        raise InvalidParameter("target", f"must be 'module:Class' or a Rig class, got {target!r}")
    _registered[kind] = target


def rig_kinds() -> dict[str, str]:
    """Every known kind: built-ins, then entry points, then :func:`register_rig` (later wins)."""
    kinds = {**BUILTIN, **_plugin_kinds()}
    kinds.update({k: v if isinstance(v, str) else f"{v.__module__}:{v.__qualname__}" for k, v in _registered.items()})
    return kinds


@functools.cache
def _plugin_kinds() -> dict[str, str]:
    """The entry points' kinds, looked up once a process: scanning the installed distributions
    takes ~15 ms, and a command asks for a rig class several times (a table: four)."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def rig_class(kind: str) -> type[Rig]:
    """Import and return the class registered for ``kind``, checked against the Rig contract."""
    if isinstance(_registered.get(kind), type):
        return _registered[kind]  # type: ignore[return-value]
    kinds = rig_kinds()
    if kind not in kinds:
        raise InvalidParameter("kind", f"unknown rig kind {kind!r}; known: {sorted(kinds)}")
    module_name, _, attr = kinds[kind].partition(":")
    try:
        cls = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InvalidParameter("kind", f"rig kind {kind!r} -> {kinds[kind]!r} cannot be imported: {exc}") from None
    check_contract(kind, cls, kinds[kind])
    return cls


def check_contract(kind: str, cls: object, target: str) -> None:
    """Raise InvalidParameter unless ``cls`` is a concrete :class:`Rig` whose contract hooks are
    class methods and whose ``PARAMETERS``/``NOISE`` are schemas."""
    where = f"rig kind {kind!r} -> {target!r}"
    if not (isinstance(cls, type) and issubclass(cls, Rig)):
        raise InvalidParameter("kind", f"{where} is not a Rig class")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise InvalidParameter("kind", f"{where} does not implement {missing} (see docs/writing-a-rig.md)")
    for hook in (
        "validate_parameters",
        "validate_noise",
        "nominal_info",
        "overridable",
        "check_overrides",
        "from_config",
    ):
        if not inspect.ismethod(getattr(cls, hook)):  # a class method is bound to the class
            raise InvalidParameter("kind", f"{where}: {hook} must be a classmethod")
    for schema in ("PARAMETERS", "NOISE"):
        if not isinstance(getattr(cls, schema), Mapping):
            raise InvalidParameter("kind", f"{where}: {schema} must be a mapping of Param")
