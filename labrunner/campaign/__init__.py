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

import importlib
from typing import Any

# loaded on first use, so that importing one submodule (``status`` reads only the ledger) does not
# load campaign validation with its controllers and numerics
_EXPORTS = {
    "Ledger": "ledger",
    "RunRecord": "ledger",
    "Campaign": "spec",
    "PlannedPoint": "spec",
    "load": "spec",
    "plan": "spec",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"labrunner.campaign.{_EXPORTS[name]}"), name)
