"""``labrunner analyse DIR [--out DIR/report] [--plot WHICH] [--recompute] [--json]``: metrics
table, maps and an HTML report."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from labrunner.cli.argtypes import path_text, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "analyse",
        help="turn a campaign directory into metrics, maps and an HTML report",
        description=(
            "Read the ledger of a campaign directory (every run's metrics are committed there); write "
            "metrics.csv/.parquet, RMS and input-energy maps with the thesis's markers and stability bounds, "
            "plots of the best, worst completed and first aborted runs (and of those --plot names), and "
            "index.html with a sortable table of all runs linking to their logs and plots."
        ),
    )
    p.add_argument("directory", type=path_text, metavar="DIR", help="campaign directory (holds ledger.sqlite)")
    p.add_argument("--out", type=path_text, metavar="DIR", help="output directory (default: DIR/report)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.add_argument(
        "--workers",
        type=positive_int,
        metavar="N",
        help="processes reading logs and drawing figures (default: all cores; 1: all in this process)",
    )
    p.add_argument(
        "--margin",
        type=float,
        default=0.1,
        metavar="F",
        help="leave out points within this relative distance of a predicted bound (default 0.1)",
    )
    p.add_argument(
        "--error",
        choices=("e", "e_hat"),
        default="e",
        help="rank runs and draw the RMS map by e (default) or by paper 2's delayed error ê",
    )
    p.add_argument(
        "--plot",
        action="append",
        default=[],
        metavar="WHICH",
        help="also plot these runs into OUT/plots/: a point id, an outcome (aborted, completed, no-motion, "
        "failed) or all; repeat or separate by commas",
    )
    p.add_argument(
        "--format",
        default="png",
        metavar="LIST",
        help="figure formats, comma-separated: png, pdf, svg (vector, fonts embedded); the PNG is always "
        "written, for the report (default png)",
    )
    p.add_argument("--dpi", type=float, default=None, metavar="N", help="resolution of the PNGs (default 110)")
    p.add_argument(
        "--size",
        choices=("screen", "column", "page"),
        default="screen",
        help="figure width: screen (7.5 in, the report's), column (3.5 in: one column of a two-column "
        "paper) or page (7.16 in: across both)",
    )
    p.add_argument(
        "--no-title",
        action="store_true",
        help="draw no titles in the figures (a paper's caption says what they show)",
    )
    p.add_argument(
        "--recompute",
        action="store_true",
        help="read every run log and compute the metrics again instead of taking the ledger's",
    )
    p.set_defaults(func=run)


def _strict(value: Any) -> Any:
    """JSON without NaN/inf (as null)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    return value


def _params(run: dict) -> str:
    return ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in run["params"].items())


def run(args: argparse.Namespace) -> int:
    from labrunner.analysis.analyse import analyse
    from labrunner.errors import InvalidParameter

    if args.out is not None:  # the path itself, or a folder above it, being a file
        blocked = next((p for p in (Path(args.out), *Path(args.out).parents) if p.exists() and not p.is_dir()), None)
        if blocked is not None:
            raise InvalidParameter("--out", f"{str(blocked)!r} exists and is not a directory")
    if not (0.0 <= args.margin < 1.0):
        raise InvalidParameter("--margin", f"must be in [0, 1), got {args.margin}")
    from labrunner.campaign.ledger import Ledger

    with Ledger.open_readonly(Path(args.directory)):  # a missing or damaged ledger: one line, before any progress
        pass
    from labrunner.analysis.png import DPI, FigureStyle, parse_formats
    from labrunner.campaign.progress import format_counts
    from labrunner.errors import check_finite

    dpi = DPI if args.dpi is None else check_finite("--dpi", args.dpi)
    style = FigureStyle(parse_formats(args.format), dpi, args.size, not args.no_title)
    plot = [word for item in args.plot for word in item.split(",") if word]
    summary = analyse(
        args.directory,
        args.out,
        workers=args.workers,
        margin=args.margin,
        error=args.error,
        recompute=args.recompute,
        plot=plot,
        style=style,
    )
    if args.json:
        print(json.dumps(_strict(summary), ensure_ascii=False))
        return 0
    agree = summary["agreement"]
    print(
        f"{summary['runs']} runs of {summary['points']} points: {format_counts(summary['outcomes'])}"
        + (f" ({summary['oscillating']} of the completed oscillating)" if summary.get("oscillating") else "")
    )
    best, pick = summary["best"], (summary.get("guided") or {}).get("chosen")
    error = "ê" if args.error == "e_hat" else "e"
    if pick:  # a guided campaign's answer is its procedure's choice, as `status` says
        print(f"chosen by the procedure (step {pick['step']}): RMS(e) = {pick['rms_error']:.4g} at {_params(pick)}")
    if best and not (pick and best["id"] == pick["id"]):
        what = "lowest RMS of its runs (not the procedure's choice)" if pick else "best"
        print(f"{what}: RMS({error}) = {best['rms']:.4g} at {_params(best)}")
    if agree.get("share") is not None:
        print(
            f"theory ({agree['case']}) agrees on {agree['share']:.1%} of {agree['n_compared']} points "
            f"({agree['n_excluded']} within ±{agree['margin']:.0%} of a bound left out)"
        )
        if agree["false_unstable"] and not agree["observed_unstable"]:
            print("  no run was aborted, so no outcome can confirm a predicted instability: read the RMS map")
    if summary.get("law_check"):
        from labrunner.rigs.device.lawflag import line

        print(line(summary["law_check"]))
    if "timing" in summary:
        from labrunner.campaign.rig_timing import timing_line

        print(timing_line(summary["timing"]))
    for problem in summary["problems"]:
        print(f"{problem['kind']}: {problem['path']}: {problem['detail']}")
    print(f"report: {summary['report']}")
    return 0
