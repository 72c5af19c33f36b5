"""How the analysis saves its figures: one resolution and compression for maps and run plots,
written atomically. Imports no matplotlib itself (the figures do), so that ``analyse`` can load
this module before it forks the child that draws the run plots."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from labrunner import safefs

DPI = 110
#: zlib level of the PNGs: 3 encodes a map in ~20 instead of ~30 ms (level 6) for files within a few per cent.
PNG_COMPRESSION = 3


def save(fig: Any, path: Path) -> Path:
    """Save atomically (temporary name, then rename): a killed analysis leaves no half a PNG."""
    with safefs.atomic_path(path) as tmp:  # an unpredictable name, never a planted link
        fig.savefig(tmp, dpi=DPI, format="png", pil_kwargs={"compress_level": PNG_COMPRESSION})
    return path


def warm_text() -> None:
    """Load the fonts and mathtext's grammar (the log axes' 10^k labels, the run plots' Ω_r) now:
    in a process about to fork a child that draws, so that the child shares them instead of
    loading them again (~65 ms)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.mathtext import MathTextParser

    MathTextParser("agg").parse(r"$\mathdefault{10^{2}}$", DPI, FontProperties())
