"""What the analysis knows about a campaign beyond its metrics table: :class:`Context` (directory,
the campaign as loaded from the ledger, the varying axes, units) and :class:`Theories` (the
stability theory that fits each table row). Its own module so that ``analyse`` and ``figures``
both import it, neither the other.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from labrunner.analysis.overlays import Theory
from labrunner.campaign.spec import Campaign
from labrunner.control import factory
from labrunner.control.mfc import gamma_scale
from labrunner.errors import InvalidParameter


@dataclass
class Context:
    """What the analysis knows about the campaign beyond the table."""

    directory: Path
    out: Path
    campaign: Campaign | None  # when its file and rig could be loaded
    note: str  # why the campaign could not be loaded ("" if it could)
    axes: list[str]  # grid axis keys that vary, in grid order
    units: dict[str, str]  # unit per dotted key and per metric column
    error: str = "e"  # which error the RMS maps and the best run use: "e", or "ê" (paper 2's delayed error)


def _delay(config: Mapping[str, Any], fs: float) -> float | None:
    """δ_t [s] of the point's differentiator (None if it has none or it is invalid)."""
    if not config.get("differentiator"):
        return None
    try:
        return factory.differentiators([config], fs, 0)[0].delay_s
    except InvalidParameter:
        return None


class Theories:
    """Theory (kind, δ_t, rig constants with the point's ``rig_parameters`` overrides) per table
    row; δ_t cached per differentiator setting."""

    def __init__(self, campaign: Campaign | None) -> None:
        self.campaign = campaign
        self._delays: dict[str, float | None] = {}

    def config(self, row: Mapping[str, Any]) -> dict[str, Any]:
        params = {k: row[k] for k in row.keys() if "." in k and pd.notna(row[k])}
        return self.campaign.resolve(params)

    def gains(self, row: Mapping[str, Any]) -> dict[str, float]:
        """γ, k_p, k_d of the row's resolved controller section (grid values and fixed ones)."""
        controller = self.config(row).get("controller", {})
        return {k: float(v) for k in ("gamma", "k_p", "k_d") if isinstance(v := controller.get(k), (int, float))}

    def __call__(self, row: Mapping[str, Any]) -> Theory | None:
        if self.campaign is None:
            return None
        config = self.config(row)
        fs = float(config["campaign"]["fs"])
        section = config.get("differentiator", {})
        key = json.dumps([section, fs], sort_keys=True, default=str)
        if key not in self._delays:
            self._delays[key] = _delay(config, fs)
        delay = self._delays[key]
        kind = config.get("controller", {}).get("kind")
        if delay is None or not isinstance(kind, str):
            return None
        overrides = {k: float(v) for k, v in (config.get("rig_parameters") or {}).items() if k in ("a", "b", "rho")}
        constants = {**self.campaign.rig_info.constants, **overrides}
        if "rho" in constants:  # ρ in the unit controller.gamma is given in (the valve's m³/(A s²))
            constants["rho"] = float(constants["rho"]) / gamma_scale(config["controller"].get("output"))
        dead_time = float(constants.get("sensor_delay", 0.0))  # a measurement delay adds to δ_t in the loop
        return Theory(kind, delay + dead_time, constants, dead_time)
