"""A campaign's run configuration as a tree of TOML data: copying it fast, setting a dotted key,
listing its dotted keys, and the names a ``[derived]`` expression may read (used by
:mod:`labrunner.campaign.spec` for every point, so kept free of anything but the standard library)."""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping
from typing import Any

_ATOMS = (str, int, float, bool, type(None))


def copy_tree(value: Any) -> Any:
    """``copy.deepcopy`` of TOML data (dicts, lists, scalars), ~5× faster: a campaign resolves
    every point two or three times (plan, batch keys, scheduler), 30 000 copies at 10 000 points.
    Anything else is handed to ``copy.deepcopy``."""
    if isinstance(value, _ATOMS):
        return value
    if type(value) is dict:
        return {k: v if isinstance(v, _ATOMS) else copy_tree(v) for k, v in value.items()}
    if type(value) is list:
        return [v if isinstance(v, _ATOMS) else copy_tree(v) for v in value]
    return copy.deepcopy(value)


class NameView(Mapping[str, Any]):
    """Names an expression may read: rig constants, then dotted keys of the resolved point."""

    def __init__(self, config: Mapping[str, Any], constants: Mapping[str, float]) -> None:
        self._config, self._constants = config, constants

    def __getitem__(self, name: str) -> Any:
        if name in self._constants:
            return self._constants[name]
        node: Any = self._config
        for part in name.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise KeyError(name)
            node = node[part]
        return node

    def __iter__(self):  # pragma: no cover - Mapping protocol
        return iter(self._constants)

    def __len__(self) -> int:  # pragma: no cover - Mapping protocol
        return len(self._constants)


def set_key(config: dict[str, Any], key: str, value: Any) -> None:
    node = config
    *parents, leaf = key.split(".")
    for part in parents:
        node = node.setdefault(part, {})
    node[leaf] = copy_tree(value)


def dotted_keys(table: Mapping[str, Any], prefix: str) -> Iterator[str]:
    for key, value in table.items():
        path = f"{prefix}.{key}"
        yield path
        if isinstance(value, Mapping):
            yield from dotted_keys(value, path)
