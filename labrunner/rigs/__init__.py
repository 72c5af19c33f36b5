"""Rigs: the one Rig interface, the registry of rig kinds, simulated twins and real-rig transports.

The Rig interface's names are imported on first use (PEP 562): a light command that only needs
a small submodule (``status`` reads :mod:`labrunner.rigs.device.lawflag`) loads no numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__all__ = ["Faults", "Rig", "RigInfo", "Signal"]

if TYPE_CHECKING:
    from labrunner.rigs.base import Faults, Rig, RigInfo, Signal


def __getattr__(name: str) -> Any:
    """The Rig interface's names, imported from :mod:`labrunner.rigs.base` when first asked for."""
    if name in __all__:
        from labrunner.rigs import base

        return getattr(base, name)
    raise AttributeError(f"module 'labrunner.rigs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
