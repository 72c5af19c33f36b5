"""Simulated twins: batch-vectorised plant models behind the :class:`~labrunner.rigs.base.Rig` interface.

:class:`SimRig` is the common base of the twins (``dcmotor``, ``valve``, ``plate``). A subclass
declares

- ``PARAMETERS`` and ``NOISE``: ``{key: Param}`` schemas of the rig file's ``[parameters]`` and
  ``[noise]`` sections (defaults, units, allowed ranges, and where each value comes from);
- ``nominal_info(name, description, parameters) -> RigInfo`` (class method): signals, physical
  limits, allowed sampling rates, safe input and the nominal constants (``RigInfo.constants``);
- ``_reset(batch, seeds, overrides)`` and ``_step(u)`` as for any Rig; in ``_reset`` it calls
  :meth:`SimRig.per_run` to get every parameter as a (B,) array with the per-run ``overrides``
  (keys of ``PARAMETERS`` or ``NOISE``; NaN entries keep the nominal value) applied and validated, and uses
  :class:`labrunner.rigs.sim._noise.NoiseStreams` so that run i's noise depends only on its seed;
- rules between parameters in ``validate_parameters`` (the rig file) and ``check_overrides``
  (per-run values), so that a campaign checks them before anything runs.

Shared numerics live in :mod:`labrunner.rigs.sim._integrate` (sub-step counts, exact
zero-order-hold discretisation, first-order decays, the play operator, sensor delay lines).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np

from labrunner.errors import InvalidParameter
from labrunner.rigs.base import Rig, RigConfig
from labrunner.rigs.config import config_from_dict, rig_info
from labrunner.rigs.schema import Schema


class SimRig(Rig):
    """Base of the simulated twins: rig-file plumbing and per-run parameters."""

    KIND: ClassVar[str]

    def __init__(self, config: RigConfig | None = None) -> None:
        if config is None:
            config = config_from_dict({"rig": {"kind": self.KIND}})
        if config.kind != self.KIND:
            raise InvalidParameter("rig.kind", f"{type(self).__name__} needs kind {self.KIND!r}, got {config.kind!r}")
        super().__init__(rig_info(config), config.faults)
        self.config = config

    # -- the Rig contract ----------------------------------------------------------------------
    @classmethod
    def overridable(cls) -> Schema:
        """Every parameter and noise level (the numeric ones may vary per run)."""
        return {**cls.PARAMETERS, **cls.NOISE}

    @classmethod
    def from_config(cls, config: RigConfig) -> SimRig:
        return cls(config)

    # -- helpers for subclasses ----------------------------------------------------------------
    def per_run(self, batch: int, overrides: Mapping[str, Any]) -> dict[str, np.ndarray]:
        """Every numeric parameter and noise level as a (B,) array, ``overrides`` applied.

        An override is a scalar or a (B,) array; NaN entries keep the rig file's value for that run.
        """
        return self.check_overrides(self.config, overrides, batch)
