"""The logged columns of a device-loop run, in the order the sample blocks carry them (pure).

Per tick, float32: the inputs u, the measured outputs y, the controlled outputs computed from
them that are not measured (Ω), the references y_r, the estimates (f̂, ê, ê̇ per output) — the
engine's tick-log order (docs/architecture.md). The errors e = y − y_r are not sent; the host
computes them as the engine does, so that a device run's signals are named and grouped exactly
as a twin run's.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from labrunner.control.base import Controller
from labrunner.engine import channel_names
from labrunner.rigs.base import RigInfo


def column_names(channels: Mapping[str, object]) -> list[str]:
    """Column order of the sample blocks for a result's channel groups."""
    groups = ("inputs", "outputs", "controlled", "references", "estimates")
    return [name for group in groups for name in channels[group]]  # type: ignore[attr-defined]


def column_count(rig_info: RigInfo, controller: Controller) -> int:
    """How many columns a run of ``controller`` on this rig logs per tick."""
    return len(column_names(channel_names(rig_info, controller)))


def to_columns(signals: Mapping[str, np.ndarray], channels: Mapping[str, object]) -> np.ndarray:
    """(K, n_columns) float32 of a run's signals, in block order."""
    names = column_names(channels)
    if not names:
        return np.zeros((0, 0), np.float32)
    return np.stack([np.asarray(signals[n], np.float32) for n in names], axis=1)


def from_columns(columns: np.ndarray, channels: Mapping[str, object]) -> dict[str, np.ndarray]:
    """The named signals of a run from its (K, n_columns) samples, as the engine names them:
    measured outputs, inputs, then per controlled output its value, reference and error, then
    the estimates (float64; e = y − y_r computed here)."""
    col = dict(zip(column_names(channels), np.asarray(columns, float).T))
    outputs = [ref[len("ref_") :] for ref in channels["references"]]  # type: ignore[attr-defined]
    sig = {n: col[n] for n in channels["outputs"]}  # type: ignore[attr-defined]
    sig.update((n, col[n]) for n in channels["inputs"])  # type: ignore[attr-defined]
    for o in outputs:
        sig[o], sig[f"ref_{o}"] = col[o], col[f"ref_{o}"]
        sig[f"e_{o}"] = sig[o] - sig[f"ref_{o}"]
    sig.update((n, col[n]) for n in channels["estimates"])  # type: ignore[attr-defined]
    return sig
