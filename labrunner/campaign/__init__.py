"""Campaigns: a grid of runs described in TOML, a SQLite ledger, crash-safe parallel execution.

- :mod:`.spec` — campaign files → validated :class:`Campaign`, grid expansion, stable point ids,
  static checks of every point (:mod:`.grid`, :mod:`.expressions`, :mod:`.checks`);
- :mod:`.ledger` — one SQLite (WAL) row per point: planned → claimed → done | aborted | failed;
- :mod:`.worker` — runs a batch in a worker and publishes each log atomically;
- :mod:`.scheduler` — batches, executors (process pool, Dask, in-process), Ctrl-C;
- :mod:`.recovery`, :mod:`.lock` — what ``resume`` does after a crash, one runner per directory;
- :mod:`.runner` — the ``run`` / ``resume`` / ``status`` operations; :mod:`.progress` — the bar.

File format and guarantees: ``docs/campaigns.md``.
"""

from labrunner.campaign.ledger import Ledger, RunRecord
from labrunner.campaign.spec import Campaign, PlannedPoint, load, plan

__all__ = ["Campaign", "Ledger", "PlannedPoint", "RunRecord", "load", "plan"]
