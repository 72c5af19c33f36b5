"""``labrunner reproduce``: run the campaign pack and write one report beside the sources' claims.

The pack (:mod:`labrunner.reproduce.items`) maps each figure or table of the thesis and the two
papers to campaign files under ``campaigns/thesis``, ``campaigns/valve-paper`` and
``campaigns/plate-paper`` (and the top-level campaigns for Figs. 3.10, 3.14 and paper 2 Fig. 4).
:func:`reproduce` runs them (:mod:`labrunner.reproduce.run`), applies each item's check
(:mod:`labrunner.reproduce.checks`, :mod:`labrunner.reproduce.checks_papers`) and writes
``OUT/index.html``: per item the source's claim, the measured check, whether they agree — stated
plainly where the twin disagrees — the numbers side by side and the campaign's maps; plus the
Guideline 2 vs Polack step counts of the guided campaigns where that module is present.
"""

from __future__ import annotations

from typing import Any

__all__ = ["reproduce"]


def __getattr__(name: str) -> Any:
    """``reproduce`` on first use: the report imports pandas, matplotlib and the stability solver,
    which ``labrunner --help`` and ``labrunner run`` (whose parser lists the pack's items) do not need."""
    if name == "reproduce":
        from labrunner.reproduce.report import reproduce

        return reproduce
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
