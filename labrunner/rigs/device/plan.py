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
        description.build(point, info, fs=fs, duration=duration, seed=campaign.seed, rig_safety=campaign.rig_safety)
