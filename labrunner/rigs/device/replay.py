"""A rig whose measurements are a given table: the law run on recorded or prescribed y[k] (pure).

The engine's closed loop on a :class:`ReplayRig` is the control law alone, open at the plant:
the controller, the reference and the safety routine run exactly as in any run, but y[k] comes
from a table, whatever input was applied. Two uses at the device loop's edges:

* the reference-law check (:mod:`labrunner.rigs.device.lawcheck`) replays a device run's logged
  measurements to recompute the inputs the device should have applied;
* conformance vectors (:mod:`labrunner.rigs.device.vectors`) and a device's *sensor table* mode
  (docs/device-loop.md, record SENSOR_TABLE): the device reads y[k] from the host's table
  instead of its sensors, so the law runs and no plant moves.

Past the table's end a run either holds its last row (the sensor-table rule, like the reference
table's) or measures NaN (a replay: the safety routine's ``non_finite_output`` then ends a run
that the device ended earlier).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from labrunner import engine
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import Rig, RigInfo


class ReplayRig(Rig):
    """B runs measuring ``tables[b, k]`` at tick k (tables (B, K, n_outputs)) whatever the input."""

    def __init__(self, info: RigInfo, tables: np.ndarray, *, hold_last: bool) -> None:
        super().__init__(info)
        self.tables = np.asarray(tables, dtype=float)
        if self.tables.ndim != 3 or self.tables.shape[2] != len(info.outputs) or self.tables.shape[1] < 1:
            raise InvalidParameter(
                "sensor_table", f"needs shape (runs, ticks ≥ 1, {len(info.outputs)}), got {self.tables.shape}"
            )
        self.hold_last = hold_last

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        """Not a rig kind of its own: a replay rig takes the info of the rig it stands in for."""
        raise InvalidParameter("rig.kind", "a replay rig is built from another rig's info, not from a rig file")

    def _row(self, k: int) -> np.ndarray:
        K = self.tables.shape[1]
        if k < K:
            return self.tables[:, k].copy()
        if self.hold_last:
            return self.tables[:, K - 1].copy()
        return np.full((self.batch, self.tables.shape[2]), np.nan)

    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        if batch != self.tables.shape[0]:
            raise InvalidParameter("batch", f"the replay holds {self.tables.shape[0]} tables, got batch {batch}")
        return self._row(0)

    def _step(self, u: np.ndarray) -> np.ndarray:
        return self._row(self.k + 1)


def replay(
    point: Mapping[str, object],
    info: RigInfo,
    tables: np.ndarray,
    *,
    fs: float,
    duration: float,
    seed: int = 0,
    rig_safety: Mapping[str, object] | None = None,
    hold_last: bool = False,
) -> list[engine.RunResult]:
    """The engine's runs of ``point`` on the measurement tables (B, K, n_outputs), one result each."""
    rig = ReplayRig(info, tables, hold_last=hold_last)
    B = rig.tables.shape[0]
    return engine.run_batch([point] * B, rig, fs=fs, duration=duration, seeds=[seed] * B, rig_safety=rig_safety)


def stack_signals(result: engine.RunResult, names: Sequence[str]) -> np.ndarray:
    """(K, len(names)) float64 of a result's named signals."""
    return np.stack([np.asarray(result.signals[n], float) for n in names], axis=1)
