"""The public face of the rigs: :func:`load_rig` and the table of kinds.

``load_rig`` finds and validates a rig file (:mod:`labrunner.rigs.config`), looks its kind up
(:mod:`labrunner.rigs.kinds`: built-ins, the entry point group ``labrunner.rigs``,
:func:`register_rig`) and builds the rig with the kind's ``from_config``. The layers below import
nothing from here, so there is no cycle: ``schema`` → ``base`` → ``kinds`` → ``config`` → ``registry``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from typing import Any

from labrunner.rigs.base import Rig, RigConfig
from labrunner.rigs.config import config_from_dict, load_rig_config
from labrunner.rigs.kinds import BUILTIN, ENTRY_POINT_GROUP, register_rig, rig_class, rig_kinds

__all__ = [
    "BUILTIN",
    "ENTRY_POINT_GROUP",
    "load_rig",
    "load_rig_config",
    "register_rig",
    "rig_class",
    "rig_kinds",
]


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
