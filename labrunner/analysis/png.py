"""How the analysis saves its figures: one resolution and compression for maps and run plots,
written atomically, in the formats and at the size a :class:`FigureStyle` asks (a paper's
one- or two-column width, vector PDF/SVG with their fonts embedded). Imports no matplotlib itself
(the figures do), so that ``analyse`` can load this module before it forks the child that draws
the run plots."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from labrunner import safefs
from labrunner.errors import InvalidParameter

DPI = 110
#: zlib level of the PNGs: 3 encodes a map in ~20 instead of ~30 ms (level 6) for files within a few per cent.
PNG_COMPRESSION = 3
FORMATS = ("png", "pdf", "svg")
#: Figure widths [in]: a journal's single column and full page (two columns: IEEE 3.5 and 7.16 in).
WIDTHS = {"screen": 7.5, "page": 7.16, "column": 3.5}
#: Text size [pt] at each width: 10 pt on screen and across a page, 8 pt in a column.
FONT_SIZES = {"screen": 10.0, "page": 9.0, "column": 7.5}


@dataclass(frozen=True)
class FigureStyle:
    """How figures are drawn and saved: ``formats`` beside the PNG (which the report shows, so it is
    always written), ``dpi`` of the PNG, ``size`` (:data:`WIDTHS`), ``title`` (False: none, for a
    caption to replace)."""

    formats: tuple[str, ...] = ("png",)
    dpi: float = DPI
    size: str = "screen"
    title: bool = True

    def __post_init__(self) -> None:
        unknown = [f for f in self.formats if f not in FORMATS]
        if unknown or not self.formats:
            raise InvalidParameter("format", f"must be one or more of {', '.join(FORMATS)}, got {self.formats}")
        if not 10 <= self.dpi <= 1200:
            raise InvalidParameter("dpi", f"must be in [10, 1200], got {self.dpi}")
        if self.size not in WIDTHS:
            raise InvalidParameter("size", f"must be one of {', '.join(WIDTHS)}, got {self.size!r}")

    @property
    def width(self) -> float:
        """Figure width [in]."""
        return WIDTHS[self.size]

    @contextmanager
    def drawing(self) -> Iterator[None]:
        """matplotlib's settings while a figure is made and saved: the text size of the width, and
        fonts embedded (TrueType in PDF, text as paths in SVG), so that a journal's checks pass."""
        import matplotlib

        with matplotlib.rc_context(
            {"font.size": FONT_SIZES[self.size], "pdf.fonttype": 42, "ps.fonttype": 42, "svg.fonttype": "path"}
        ):
            yield


def parse_formats(text: str) -> tuple[str, ...]:
    """``--format png,pdf,svg`` as a tuple (PNG first: the report's), each format once."""
    formats = [f.strip().lower() for f in text.split(",") if f.strip()]
    unknown = [f for f in formats if f not in FORMATS]
    if unknown or not formats:
        raise InvalidParameter("--format", f"must be one or more of {', '.join(FORMATS)}, got {text!r}")
    return tuple(dict.fromkeys(["png", *formats]))


def save(fig: Any, path: Path, style: FigureStyle | None = None) -> Path:
    """Save ``path`` (a PNG) and, beside it, the style's other formats; each atomically (temporary
    name, then rename: a killed analysis leaves no half a file). Returns the PNG's path."""
    style = style or FigureStyle()
    with style.drawing():
        for fmt in dict.fromkeys(["png", *style.formats]):
            target = path.with_suffix(f".{fmt}")
            extra = (
                {"pil_kwargs": {"compress_level": PNG_COMPRESSION}} if fmt == "png" else {"metadata": _metadata(fmt)}
            )
            with safefs.atomic_path(target) as tmp:  # an unpredictable name, never a planted link
                fig.savefig(tmp, dpi=style.dpi, format=fmt, **extra)
    return path


def _metadata(fmt: str) -> dict[str, Any]:
    """No creation date in a vector file: the same figure gives the same bytes."""
    return {"CreationDate": None} if fmt == "pdf" else {"Date": None}


def warm_text() -> None:
    """Load the fonts and mathtext's grammar (the log axes' 10^k labels, the run plots' Ω_r) now:
    in a process about to fork a child that draws, so that the child shares them instead of
    loading them again (~65 ms)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.mathtext import MathTextParser

    MathTextParser("agg").parse(r"$\mathdefault{10^{2}}$", DPI, FontProperties())
