"""Campaign results in Python (docs/python.md): :func:`open_campaign` → :class:`CampaignResults`
(the metrics table from the ledger, selection, runs, point × time signals), :func:`open_run` →
:class:`RunResults` (one run's signals with units, config, outcome, diagnostics), :class:`Catalog`
(several campaign directories)."""

from labrunner.results.campaign import CampaignResults, open_campaign, open_run
from labrunner.results.catalog import Catalog
from labrunner.results.conditions import near
from labrunner.results.run import OUTCOME_KEYS, RunResults

__all__ = ["OUTCOME_KEYS", "Catalog", "CampaignResults", "RunResults", "near", "open_campaign", "open_run"]
