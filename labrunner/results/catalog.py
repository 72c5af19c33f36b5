"""Several campaign directories at once: one table with a ``campaign`` column, and each campaign
by name. Directories are given, or found below a folder (every sub-folder holding a ledger)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd

from labrunner.campaign.ledger import LEDGER_NAME
from labrunner.errors import InvalidParameter
from labrunner.results.campaign import CampaignResults


class Catalog:
    """Campaign directories by name (the campaign's name, else the folder's; made unique by the
    folder's path where two share one)."""

    def __init__(self, directories: Iterable[str | Path]) -> None:
        self.campaigns: dict[str, CampaignResults] = {}
        for directory in directories:
            results = CampaignResults(directory)
            name = results.name
            if name in self.campaigns:
                name = str(Path(directory))
            self.campaigns[name] = results

    @classmethod
    def find(cls, root: str | Path) -> Catalog:
        """Every campaign directory below ``root`` (``root`` itself included)."""
        root = Path(root)
        if not root.is_dir():
            raise InvalidParameter("root", f"{str(root)!r} is not a directory")
        return cls(sorted(p.parent for p in root.rglob(LEDGER_NAME)))

    def __repr__(self) -> str:
        return f"Catalog({list(self.campaigns)})"

    def __len__(self) -> int:
        return len(self.campaigns)

    def __iter__(self) -> Iterator[str]:
        return iter(self.campaigns)

    def __getitem__(self, name: str) -> CampaignResults:
        try:
            return self.campaigns[name]
        except KeyError:
            raise InvalidParameter(
                "campaign", f"{name!r} is not in the catalog; it holds {list(self.campaigns)}"
            ) from None

    def summary(self) -> pd.DataFrame:
        """One row per campaign: ``campaign``, ``rig``, ``date`` (created, UTC), ``description``,
        ``points``, the count of each outcome, ``directory``; from the ledgers (no table built)."""
        rows = [{"campaign": name, **_about(c)} for name, c in self.campaigns.items()]
        if not rows:
            return pd.DataFrame(columns=["campaign", *ABOUT])
        frame = pd.DataFrame(rows)
        outcomes = [c for c in frame.columns if c not in ("campaign", *ABOUT)]
        frame[outcomes] = frame[outcomes].fillna(0).astype(int)  # a campaign without that outcome: 0 points
        return frame[["campaign", *ABOUT[:-1], *outcomes, ABOUT[-1]]]

    def latest(self) -> CampaignResults:
        """The campaign created last (the ledger's creation time)."""
        if not self.campaigns:
            raise InvalidParameter("catalog", "holds no campaign")
        return max(self.campaigns.values(), key=lambda c: _created(c) or 0.0)

    def search(self, text: str | None = None, /, **fields: Any) -> Catalog:
        """The campaigns whose ``[metadata]`` has every field as given (equal, or among a list's
        items such as tags; strings without case) and, with ``text``, holds it in some value:
        ``catalog.search(operator="ana", tags="friction")``, ``catalog.search("batch 7")``."""
        from labrunner.campaign.metadata import matches

        found = Catalog([])
        found.campaigns = {n: c for n, c in self.campaigns.items() if matches(c.metadata, text, **fields)}
        return found

    def table(self) -> pd.DataFrame:
        """Every campaign's table, one below the other, with first columns ``campaign``, ``rig``,
        ``date`` and ``description``; a parameter one campaign lacks is empty in its rows."""
        frames = [c.table().assign(campaign=name, **_about(c, counts=False)) for name, c in self.campaigns.items()]
        if not frames:
            return pd.DataFrame(columns=["campaign", *ABOUT[:3]])
        frame = pd.concat(frames, ignore_index=True)
        first = ["campaign", *ABOUT[:3]]
        return frame[[*first, *(c for c in frame.columns if c not in first)]]


#: Columns of :meth:`Catalog.summary` after ``campaign`` (the outcome counts come between).
ABOUT = ("rig", "date", "description", "points", "directory")


def _created(campaign: CampaignResults) -> float | None:
    try:
        return float(campaign.meta.get("created_at", ""))
    except ValueError:
        return None


def _about(campaign: CampaignResults, counts: bool = True) -> dict[str, object]:
    """A campaign's rig, creation date, description (and point counts by outcome, directory)."""
    from labrunner.results import describe

    facts = dict(describe.campaign_facts(campaign))
    created = _created(campaign)
    out: dict[str, object] = {
        "rig": facts.get("rig", ""),
        "date": pd.Timestamp(created, unit="s", tz="UTC") if created is not None else pd.NaT,
        "description": facts.get("description", ""),
    }
    if counts:
        out["points"] = int(campaign.meta.get("points") or 0)
        out.update(describe.outcome_counts(campaign))
        out["directory"] = str(campaign.directory)
    return out
