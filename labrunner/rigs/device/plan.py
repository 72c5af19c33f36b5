"""Plan-time check of where a campaign's loop runs (``labrunner run`` and ``--dry-run``).

For a rig behind a link (``can``, ``serial``): a host loop the link cannot carry at the
campaign's f_s is refused with its load and the alternative (:func:`~labrunner.rigs.transports.linkload.check_host_loop`);
a device loop builds every point's run description, so a point the device cannot run is refused
before anything is created. Simulated rigs pass unchecked.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

from labrunner.errors import InvalidParameter
from labrunner.rigs.config import load_rig_config
from labrunner.rigs.device import description
from labrunner.rigs.transports import linkload


def _device_link(campaign) -> linkload.LinkSpec | None:
    """The link of a rig whose loop runs on the device, else None."""
    if campaign.rig_info.simulated:
        return None
    config = load_rig_config(campaign.rig_ref, search=campaign.rig_search)
    if config.parameters.get("loop") != "device":
        return None
    return linkload.from_rig(config.kind, config.parameters)


def upload_s(campaign, points: Sequence) -> float:
    """Seconds the device loop's after-the-run sample uploads add to a campaign on its link
    (0 for a host loop, a simulated rig, or samples that stream during the run)."""
    link = _device_link(campaign)
    if link is None:
        return 0.0
    total, columns = 0.0, {}
    for p in points:
        fs, duration = json.loads(p.batch_key)[1:3]
        key = p.batch_key
        if key not in columns:
            data = description.build(
                campaign.resolve(p.parameters),
                campaign.rig_info,
                fs=fs,
                duration=duration,
                seed=campaign.seed,
                rig_safety=campaign.rig_safety,
            )
            columns[key] = description.decode(data).n_columns
        if linkload.device_loop_load(link, fs, columns[key]) > linkload.MAX_LOAD:
            total += linkload.upload_s(link, fs, duration, columns[key])
    return total


def check_placement(campaign, points: Sequence) -> None:
    """Raise InvalidParameter (one line) for a plan the rig's loop placement cannot run."""
    if campaign.rig_info.simulated or not points:
        return
    config = load_rig_config(campaign.rig_ref, search=campaign.rig_search)
    if "loop" not in config.parameters:
        return
    info, loop = campaign.rig_info, config.parameters["loop"]
    link = linkload.from_rig(config.kind, config.parameters)
    if loop == "host":
        for fs in sorted({json.loads(p.batch_key)[1] for p in points}):
            message = linkload.check_host_loop(link, fs, len(info.inputs), len(info.outputs))
            if message:
                raise InvalidParameter("campaign.fs", message)
        return
    for p in points:
        fs, duration = json.loads(p.batch_key)[1:3]
        point = campaign.resolve(p.parameters)
        description.build(
            point,
            info,
            fs=fs,
            duration=duration,
            seed=campaign.seed,
            rig_safety=campaign.rig_safety,
            reference_table=bool(config.parameters.get("reference_table")),
        )
