"""``labrunner plot RUN.mcap [-o run.png]``: reference, outputs, inputs and estimates of one run
over time, like the thesis's Figs. 3.12 and 3.20 (see :mod:`labrunner.runplot`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "plot",
        help="draw one run log (MCAP) to an image",
        description="Draw a run's outputs with their references, its inputs and estimates over time.",
    )
    parser.add_argument("path", metavar="RUN.mcap", help="run log to draw")
    parser.add_argument("-o", "--output", help="image file (.png, .pdf, .svg); default: RUN.png beside the log")
    parser.add_argument("--dpi", type=float, default=150.0, help="resolution of raster images (default 150)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from labrunner.errors import InvalidParameter, check_finite
    from labrunner.runplot import plot_run

    dpi = check_finite("dpi", args.dpi)
    if not 10 <= dpi <= 1200:
        raise InvalidParameter("dpi", f"must be in [10, 1200], got {args.dpi}")
    output = Path(args.output) if args.output else Path(args.path).with_suffix(".png")
    if not output.parent.is_dir():
        raise InvalidParameter("output", f"directory does not exist: {str(output.parent)!r}")
    fig = plot_run(args.path)
    try:
        fig.savefig(output, dpi=dpi)
    except ValueError as exc:  # unknown image format
        raise InvalidParameter("output", str(exc)) from None
    print(output)
    return 0
