"""What an analysis reads off its metrics table: the campaign the ledger keeps, the grid axes
that vary, the units of gains and metrics, the outcome counts, the best, worst and first aborted
runs and the runs ``--plot`` asks for."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from labrunner.analysis import agreement as agreement_mod
from labrunner.analysis.map_data import gain_units
from labrunner.campaign import spec
from labrunner.campaign.progress import FINISHED, OUTCOMES
from labrunner.campaign.spec import Campaign
from labrunner.control.mfc import GAMMA_UNITS
from labrunner.errors import InvalidParameter, LabrunnerError


def load_campaign(meta: Mapping[str, str], directory: Path) -> tuple[Campaign | None, str]:
    """The :class:`~labrunner.campaign.spec.Campaign` kept in the ledger, or (None, why not)."""
    text = meta.get("campaign_file")
    if not text:
        return None, "the ledger keeps no copy of the campaign file"
    source = meta.get("campaign_path")
    try:
        return spec.from_text(text, source_path=Path(source) if source else None), ""
    except LabrunnerError as exc:
        return None, f"the campaign file could not be loaded again: {exc}"


def rig_signals(campaign: Campaign | None) -> tuple[dict[str, str], dict[str, tuple[float, float]]]:
    """What the metrics table needs of the rig: its signals' units (for logs that record none) and
    its inputs' limits (the oscillation detector); empty without a campaign."""
    if campaign is None:
        return {}, {}
    info = campaign.rig_info
    return {s.name: s.unit for s in (*info.inputs, *info.outputs)}, {s.name: (s.lo, s.hi) for s in info.inputs}


def varying_axes(frame: pd.DataFrame, campaign: Campaign | None) -> list[str]:
    """Numeric grid axes with more than one value (the first axis of each zipped group)."""
    if campaign is not None:
        keys = [group[0].key for group in campaign.grid.groups]
    else:
        keys = [c for c in frame.columns if "." in c]
    out = []
    for key in keys:
        if key in frame.columns and pd.api.types.is_numeric_dtype(frame[key]) and frame[key].nunique() > 1:
            out.append(key)
    return out


def follows(frame: pd.DataFrame, x: str, y: str) -> bool:
    """Whether ``y`` is a monotone function of ``x`` over the table's rows, so that a line drawn
    through the runs sorted by ``x`` follows ``y`` too (True where either is not a numeric column)."""
    if not all(k in frame.columns and pd.api.types.is_numeric_dtype(frame[k]) for k in (x, y)):
        return True
    values = frame.groupby(x)[y].agg(["min", "max"])  # sorted by x
    if (values["min"] != values["max"]).any():
        return False
    steps = values["min"].diff().dropna()
    return bool((steps >= 0).all() or (steps <= 0).all())


def _signal_unit(name: str, channels: Mapping[str, Mapping[str, Any]], campaign: Campaign | None) -> str:
    """Unit of a logged signal: the log's own record, else the rig's signal of that name, else (a
    controlled output that is no rig output, i.e. the difference quotient (2.34) of one) the rig
    output's unit per second."""
    unit = str(channels.get(name, {}).get("unit") or "")
    if unit or campaign is None:
        return unit
    signals = {s.name: s.unit for s in (*campaign.rig_info.inputs, *campaign.rig_info.outputs)}
    if name in signals:
        return signals[name]
    outputs = campaign.rig_info.outputs
    return f"{outputs[0].unit}/s" if outputs and outputs[0].unit else ""


def table_units(frame: pd.DataFrame, directory: Path, campaign: Campaign | None) -> dict[str, str]:
    """Units of the gains and metrics, from the first readable log's channel record; of the rig's
    parameters a grid may vary (``rig_parameters.<key>``), from the rig kind's schema."""
    rig = rig_parameter_units(campaign)
    return {**rig, **_log_units(frame, directory, campaign)}


def rig_parameter_units(campaign: Campaign | None) -> dict[str, str]:
    """``rig_parameters.<key>`` → unit of each parameter the campaign's rig lets a grid vary."""
    if campaign is None:
        return {}
    from labrunner.rigs.kinds import rig_class

    schema = rig_class(campaign.rig_config.kind).overridable()
    return {f"rig_parameters.{key}": param.unit for key, param in schema.items() if param.unit}


def _log_units(frame: pd.DataFrame, directory: Path, campaign: Campaign | None) -> dict[str, str]:
    from labrunner.logs import read_metadata

    for path in frame["log_path"].dropna().head(5):
        try:
            channels = read_metadata(directory / path).get("channels", {})
        except (LabrunnerError, OSError, ValueError):
            continue
        errors = [c for c, i in channels.items() if i.get("role") == "error"]
        inputs = [c for c, i in channels.items() if i.get("role") == "input"]
        e_unit = _signal_unit(errors[0][2:], channels, campaign) if errors else ""
        u_unit = _signal_unit(inputs[0], channels, campaign) if inputs else ""
        units = {
            "rms_error": e_unit,
            "max_abs_input": u_unit,
            "input_energy": f"{u_unit}²" if u_unit else "",
            "max_current": "A",
        }
        kind = campaign.base.get("controller", {}).get("kind") if campaign is not None else None
        order = {"mfc1": 1, "mfc1-ff": 1, "mfc2": 2}.get(str(kind))
        if order and e_unit and u_unit:
            units.update(gain_units(order, e_unit, u_unit))
            output = campaign.base.get("controller", {}).get("output")
            units["controller.gamma"] = GAMMA_UNITS.get(output, units["controller.gamma"])
        return units
    return {}


def counts(frame: pd.DataFrame) -> dict[str, Any]:
    """Points, finished runs, points per outcome word (:data:`~labrunner.campaign.progress.OUTCOMES`),
    and ``oscillating``: completed runs the oscillation detector flags (observed unstable); on a
    real rig ``timing``: its late ticks and overruns (:mod:`labrunner.campaign.rig_timing`)."""
    found = frame["outcome"].value_counts()
    outcomes = {w: int(found.get(w, 0)) for w in OUTCOMES}
    out = {
        "points": int(len(frame)),
        "runs": sum(outcomes[w] for w in FINISHED),
        "outcomes": outcomes,
        "oscillating": int((agreement_mod.observed_outcome(frame) == "oscillating").sum()),
    }
    if "overruns" in frame.columns:  # a real rig's runs: their late ticks and overruns
        late, over = (pd.to_numeric(frame[c]) for c in ("late_ticks", "overruns"))
        out["timing"] = {
            "runs": int(over.notna().sum()),
            "late_ticks": int(late.sum()),
            "overruns": int(over.sum()),
            "runs_with_late_ticks": int((late > 0).sum()),
            "runs_with_overruns": int((over > 0).sum()),
        }
    return out


def chosen_runs(frame: pd.DataFrame) -> dict[str, pd.Series]:
    """Best and worst completed run (by RMS of e) and the first aborted run (in grid order); found
    from the columns they need, so that no subset of the table's rows is copied. A completed run
    the oscillation detector flags is observed unstable (:mod:`.agreement`): never "best" nor
    "worst completed", whose captions call them completed."""
    outcome = frame["outcome"]
    rms = frame["rms_error"].to_numpy(dtype=float)
    steady = (agreement_mod.observed_outcome(frame) == "completed").to_numpy(dtype=bool)
    done = np.flatnonzero(steady & np.isfinite(rms))
    out: dict[str, pd.Series] = {}
    if done.size:
        out["best"] = frame.iloc[done[np.argmin(rms[done])]]
        out["worst completed"] = frame.iloc[done[np.argmax(rms[done])]]
    aborted = np.flatnonzero((outcome == "aborted").to_numpy(dtype=bool))
    if aborted.size:
        out["first aborted"] = frame.iloc[aborted[np.argmin(frame["seq"].to_numpy(dtype=float)[aborted])]]
    return out


def with_procedure_choice(
    frame: pd.DataFrame, chosen: dict[str, pd.Series], campaign: Any, rows: Sequence[Mapping[str, Any]]
) -> dict[str, pd.Series]:
    """A guided campaign's :func:`chosen_runs`: the run its procedure chose first ("chosen", the one
    ``status`` names), and its "best" renamed "lowest RMS" — the lowest RMS of all its runs is not
    the procedure's answer, and one question gets one answer."""
    from labrunner.campaign import guided_run

    pick = guided_run.summary(campaign, rows).get("chosen")
    at = np.flatnonzero((frame["id"] == pick["id"]).to_numpy(dtype=bool)) if pick else []
    out = {"chosen": frame.iloc[at[0]]} if len(at) else {}
    return {**out, **{("lowest RMS" if label == "best" else label): row for label, row in chosen.items()}}


def plot_selection(frame: pd.DataFrame, plot: Sequence[str]) -> list[str]:
    """Point ids the ``--plot`` words choose: ``all``, an outcome word (``aborted``, ...) or ids."""
    ids: list[str] = []
    for word in plot:
        if word == "all":
            chosen = frame["id"]
        elif word in OUTCOMES:
            chosen = frame.loc[frame["outcome"] == word, "id"]
        elif (frame["id"] == word).any():
            chosen = [word]
        else:
            raise InvalidParameter(
                "--plot", f"must be 'all', an outcome ({', '.join(FINISHED)}) or a point id, got {word!r}"
            )
        ids += [i for i in chosen if i not in ids]
    return ids


def best_run(frame: pd.DataFrame) -> dict[str, Any] | None:
    best = chosen_runs(frame).get("best")
    if best is None:
        return None
    params = {k: _plain(best[k]) for k in frame.columns if "." in k and pd.notna(best[k])}
    return {
        "id": best["id"],
        "params": params,
        "rms": float(best["rms_error"]),
        "input_energy": float(best["input_energy"]),
    }


def _plain(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else value
