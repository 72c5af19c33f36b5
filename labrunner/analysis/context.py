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


GAIN_KEYS = ("controller.gamma", "controller.k_p", "controller.k_d")


def parameter_records(frame: pd.DataFrame, *, settings: bool = False) -> list[dict[str, Any]]:
    """The table's rows as :class:`Theories` reads them: their parameter (dotted) columns only, not
    the ~40 metric columns (a 10 000-row table's records cost ~0.1 s each time). ``settings``: one
    record per distinct setting of the parameters other than the gains (all a theory depends on)."""
    keys = [c for c in frame.columns if "." in c and (not settings or c not in GAIN_KEYS)]
    if settings:
        if not keys:
            return [{}] if len(frame) else []
        return frame[keys].drop_duplicates().to_dict("records")
    return frame[keys].to_dict("records")


class Theories:
    """Theory (kind, δ_t, rig constants with the point's ``rig_parameters`` overrides) and gains
    per table row (a mapping: a record of the table). The theory does not depend on the gains, so
    it is resolved once per distinct setting of the other parameters (δ_t once per differentiator
    setting), not once per row: a γ–k_p grid of 10 000 points has one."""

    def __init__(self, campaign: Campaign | None) -> None:
        self.campaign = campaign
        self._delays: dict[str, float | None] = {}
        self._settings: dict[tuple, tuple[dict[str, Any], Theory | None]] = {}

    def _setting(self, row: Mapping[str, Any]) -> tuple[dict[str, Any], Theory | None]:
        """(resolved configuration without the row's gains, theory) of the row's setting."""
        params = tuple(
            sorted(
                (k, v)
                for k, v in row.items()
                if "." in k and k not in GAIN_KEYS and isinstance(v, (int, float, str, bool)) and pd.notna(v)
            )
        )
        hit = self._settings.get(params)
        if hit is None:
            config = self.campaign.resolve(dict(params))
            hit = self._settings[params] = (config, self._theory(config))
        return hit

    def gains(self, row: Mapping[str, Any]) -> dict[str, float]:
        """γ, k_p, k_d of the row: its grid values, else the campaign's fixed ones."""
        config, _ = self._setting(row)
        controller = config.get("controller", {})
        out = {k: float(v) for k in ("gamma", "k_p", "k_d") if isinstance(v := controller.get(k), (int, float))}
        for key in GAIN_KEYS:
            value = row.get(key)
            if isinstance(value, (int, float)) and pd.notna(value):
                out[key.split(".", 1)[1]] = float(value)
        return out

    def __call__(self, row: Mapping[str, Any]) -> Theory | None:
        if self.campaign is None:
            return None
        return self._setting(row)[1]

    def _theory(self, config: Mapping[str, Any]) -> Theory | None:
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
