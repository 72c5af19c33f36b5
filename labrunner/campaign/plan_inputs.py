"""The digest of everything a campaign's plan is computed from, so that ``resume`` can trust a
stored plan without planning every point again.

:func:`labrunner.campaign.spec.plan` is a pure function of the campaign file's content, the rig
file it names and labrunner's own code (and numpy's, which evaluates the static checks). Planning
costs 0.2–1 ms a point (the static checks of every point), so re-planning a 10^6-point campaign
to check it on ``resume`` would take minutes; comparing this digest, written into the ledger's
``meta`` at ``run``, takes ~20 ms. When it differs (the file was edited, the rig file changed,
labrunner was upgraded or edited) ``resume`` re-plans and compares the plan checksum as before.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy

import labrunner

#: The ledger ``meta`` key holding :func:`digest` of the plan's inputs.
META_KEY = "plan_inputs"


@functools.cache
def code_digest() -> str:
    """SHA-256 over labrunner's source files (relative path and bytes, in path order) and numpy's
    version: any edit of the code that plans, even without a version change, changes it."""
    package = Path(labrunner.__file__).resolve().parent
    h = hashlib.sha256(f"numpy {numpy.__version__}\n".encode())
    for path in sorted(package.rglob("*.py")):
        h.update(f"{path.relative_to(package).as_posix()}\n".encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def digest(campaign: Any) -> str:
    """SHA-256 of a :class:`~labrunner.campaign.spec.Campaign`'s plan inputs: its file parsed
    (so a comment or layout edit keeps it), its rig file validated, and :func:`code_digest`."""
    from labrunner.campaign.spec import parse

    inputs = {
        "campaign": parse(campaign.source, source_path=campaign.source_path),
        "rig": campaign.rig,
        "rig_path": str(campaign.rig_path) if campaign.rig_path else None,
        "rig_config": campaign.rig_config.to_dict(),
        "code": code_digest(),
    }
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), default=repr, ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()
