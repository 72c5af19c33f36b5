"""``labrunner plot RUN.mcap [RUN.mcap …] [-o run.png]``: reference, outputs, inputs and estimates of one
run over time, like the thesis's Figs. 3.12 and 3.20 (see :mod:`labrunner.runplot`); several runs are
overlaid, like Figs. 3.18 and 3.22 (:mod:`labrunner.overlay`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "plot",
        help="draw one run log (MCAP), or overlay several, to an image",
        description="Draw a run's outputs with their references, its inputs and estimates over time; with several "
        "logs, overlay their outputs and inputs, each run labelled by the grid values that differ.",
    )
    parser.add_argument(
        "paths", nargs="+", type=path_text, metavar="RUN.mcap", help="run log(s) to draw (2-20 are overlaid)"
    )
    parser.add_argument(
        "-o",
        "--output",
        help="image file (.png, .pdf, .svg); default: RUN.png beside the (first) log, RUN-overlay.png for several",
    )
    parser.add_argument("--dpi", type=float, default=150.0, help="resolution of raster images (default 150)")
    parser.add_argument(
        "--size",
        choices=("screen", "column", "page"),
        default="screen",
        help="figure width: screen (7.5 in), column (3.5 in: one column of a two-column paper) or page (7.16 in)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from labrunner.analysis.png import FigureStyle
    from labrunner.errors import InvalidParameter, check_finite
    from labrunner.runplot import plot_run

    dpi = check_finite("dpi", args.dpi)
    if not 10 <= dpi <= 1200:
        raise InvalidParameter("dpi", f"must be in [10, 1200], got {args.dpi}")
    first = Path(args.paths[0])
    default = first.with_suffix(".png") if len(args.paths) == 1 else first.with_name(f"{first.stem}-overlay.png")
    output = Path(args.output) if args.output else default
    if not output.parent.is_dir():
        raise InvalidParameter("output", f"directory does not exist: {str(output.parent)!r}")
    style = FigureStyle(dpi=dpi, size=args.size)
    with style.drawing():  # the width's text size; fonts embedded in a PDF or SVG
        if len(args.paths) == 1:
            fig = plot_run(args.paths[0], width=style.width)
        else:
            from labrunner.overlay import plot_overlay

            fig = plot_overlay(args.paths)
        try:
            fig.savefig(output, dpi=dpi)
        except ValueError as exc:  # unknown image format
            raise InvalidParameter("output", str(exc)) from None
    print(output)
    return 0
