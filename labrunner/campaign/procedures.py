"""``[guided]`` of a campaign file → its :class:`~labrunner.campaign.guided.Procedure`.

The table of procedures a campaign may name, and the one function :mod:`labrunner.campaign.spec`
calls to parse ``[guided]``. Kept apart from :mod:`labrunner.campaign.guided` (the protocol the
procedures implement), so that the procedures import the protocol and this table imports the
procedures: loading a campaign goes spec → procedures → guided_walks | guided_refine → guided,
never back.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from labrunner.campaign.guided import Procedure, Table
from labrunner.campaign.guided_refine import Refine
from labrunner.campaign.guided_walks import Guideline2, Guideline3, Polack
from labrunner.errors import InvalidParameter

#: ``[guided] procedure = …`` → its class (each has ``from_table(Table, campaign)``).
PROCEDURES: dict[str, type[Procedure]] = {
    "guideline2": Guideline2,
    "guideline3": Guideline3,
    "polack": Polack,
    "refine": Refine,
}


def parse(table: Any, campaign: Any) -> Procedure:
    """``[guided]`` of a campaign → its :class:`Procedure` (``campaign``: the Campaign without it)."""
    if not isinstance(table, Mapping):
        raise InvalidParameter("guided", f"must be a table, got {table!r}")
    name = table.get("procedure")
    if name not in PROCEDURES:
        raise InvalidParameter("guided.procedure", f"must be one of {', '.join(PROCEDURES)}, got {name!r}")
    reader = Table(table, dict(campaign.rig_info.constants))
    procedure = PROCEDURES[name].from_table(reader, campaign)
    reader.done()
    tuned = {key for point in procedure.corners() for key in point}
    for key, _ in campaign.derived:
        if key in tuned:
            raise InvalidParameter(
                f'derived."{key}"', f"is set by the {name} procedure; a key is either tuned or derived"
            )
    return procedure
