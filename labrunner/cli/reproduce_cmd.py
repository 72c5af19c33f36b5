"""``labrunner reproduce [--quick] [--only FIG …] [--out DIR]``: the campaign pack in one command."""

from __future__ import annotations

import argparse
import json
import sys

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    from labrunner.reproduce.items import ITEMS

    p = subparsers.add_parser(
        "reproduce",
        help="run the thesis's and papers' campaign pack on the twins and write one report",
        description=(
            "Run the campaigns under campaigns/thesis, campaigns/valve-paper and campaigns/plate-paper (and the "
            "top-level ones they build on), analyse each, and write OUT/index.html: every map and table beside the "
            "source's claim and the measured check, saying plainly where the twin disagrees and which claims it cannot test. A second call resumes "
            "and re-analyses what OUT already holds. Figures: " + ", ".join(i.id for i in ITEMS) + "."
        ),
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="reduced grids and shortened references (about 5 min of CPU: 2.5-5 min on 2 free cores; the longest plate runs left out)",
    )
    p.add_argument("--only", nargs="+", metavar="FIG", help="run only these figures/tables (ids as listed above)")
    p.add_argument(
        "--out",
        default="data/reproduce",
        type=path_text,
        metavar="DIR",
        help="output directory (default: data/reproduce)",
    )
    p.add_argument("--workers", type=int, metavar="N", help="worker processes (default: all cores)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from labrunner.errors import InvalidParameter
    from labrunner.reproduce import reproduce
    from labrunner.reproduce.items import select

    if args.workers is not None and args.workers < 1:
        raise InvalidParameter("--workers", f"must be >= 1, got {args.workers}")
    select(tuple(args.only) if args.only else None)  # an unknown figure fails before anything runs
    say = (lambda _: None) if args.json else (lambda line: print(line, file=sys.stderr, flush=True))
    summary = reproduce(args.out, quick=args.quick, only=args.only, workers=args.workers, say=say)
    if args.json:
        print(json.dumps(summary, ensure_ascii=False, default=str))
        return 0
    for item, v in summary["items"].items():
        verdict = "DISAGREES" if v["verdict"] == "disagrees" else v["verdict"]
        print(f"{item:>11}  {verdict:17}  {v['measured']}")
    n = summary["counts"]
    print(", ".join(f"{count} {kind}" for kind, count in n.items() if count))
    print(f"report: {summary['report']} ({summary['seconds']:.0f} s)")
    return 0
