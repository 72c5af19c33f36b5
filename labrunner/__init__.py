"""labrunner: parameter campaigns of model-free control on lab rigs and their simulated twins.

The results API (docs/python.md) is exported here and imported on first use, so that
``import labrunner`` stays light (the CLI and the workers load no pandas)::

    import labrunner
    campaign = labrunner.open_campaign("data/quickstart")
    campaign.table()                      # the metrics table, as report/metrics.csv
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from labrunner.version import __version__

_RESULTS = ("open_campaign", "open_run", "Catalog", "CampaignResults", "RunResults", "OUTCOME_KEYS")
__all__ = [
    "OUTCOME_KEYS",
    "CampaignResults",
    "Catalog",
    "RunResults",
    "__version__",
    "open_campaign",
    "open_run",
]

if TYPE_CHECKING:
    from labrunner.results import OUTCOME_KEYS, CampaignResults, Catalog, RunResults, open_campaign, open_run


def __getattr__(name: str) -> Any:
    """The results API's names, imported when first asked for (PEP 562)."""
    if name in _RESULTS:
        from labrunner import results

        return getattr(results, name)
    raise AttributeError(f"module 'labrunner' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The module's names and the results API's, not yet imported (tab completion, ``dir``)."""
    return sorted({*globals(), *__all__})
