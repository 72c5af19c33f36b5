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

    def search(self, text: str | None = None, /, **fields: Any) -> Catalog:
        """The campaigns whose ``[metadata]`` has every field as given (equal, or among a list's
        items such as tags; strings without case) and, with ``text``, holds it in some value:
        ``catalog.search(operator="ana", tags="friction")``, ``catalog.search("batch 7")``."""
        from labrunner.campaign.metadata import matches

        found = Catalog([])
        found.campaigns = {n: c for n, c in self.campaigns.items() if matches(c.metadata, text, **fields)}
        return found

    def table(self) -> pd.DataFrame:
        """Every campaign's table, one below the other, with a first column ``campaign``; a
        parameter one campaign lacks is empty in its rows."""
        frames = [c.table().assign(campaign=name) for name, c in self.campaigns.items()]
        if not frames:
            return pd.DataFrame(columns=["campaign"])
        frame = pd.concat(frames, ignore_index=True)
        return frame[["campaign", *(c for c in frame.columns if c != "campaign")]]
