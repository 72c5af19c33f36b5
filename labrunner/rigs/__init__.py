"""Rigs: the one Rig interface, the registry of rig kinds, simulated twins and real-rig transports."""

from labrunner.rigs.base import Faults, Rig, RigInfo, Signal

__all__ = ["Faults", "Rig", "RigInfo", "Signal"]
