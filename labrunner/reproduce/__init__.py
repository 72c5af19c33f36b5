"""``labrunner reproduce``: run the campaign pack and write one report beside the sources' claims.

The pack (:mod:`labrunner.reproduce.items`) maps each figure or table of the thesis and the two
papers to campaign files under ``campaigns/thesis``, ``campaigns/valve-paper`` and
``campaigns/plate-paper`` (and the top-level campaigns for Figs. 3.10, 3.14 and paper 2 Fig. 4).
:func:`reproduce` runs them (:mod:`labrunner.reproduce.run`), applies each item's check
(:mod:`labrunner.reproduce.checks` and its siblings, one per source and kind) and writes
``OUT/index.html``: per item the source's claim, the measured check, whether they agree — stated
plainly where the twin disagrees — the numbers side by side and the campaign's maps; plus the
Guideline 2 vs Polack step counts of the guided campaigns where that module is present.
"""

from __future__ import annotations

from typing import Any


def reproduce(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """:func:`labrunner.reproduce.report.reproduce` (imported on use: the CLI reads the item list at start-up)."""
    from labrunner.reproduce.report import reproduce as run

    return run(*args, **kwargs)


__all__ = ["reproduce"]
