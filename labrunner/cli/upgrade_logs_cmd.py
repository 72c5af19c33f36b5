"""``labrunner upgrade-logs DIR``: rewrite a campaign's labrunner-3 logs so that Foxglove opens them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "upgrade-logs",
        help="rewrite a campaign's logs of format labrunner-3 (which Foxglove refuses) in the current layout",
        description=(
            "Rewrite every finished point's log in DIR/runs/ whose /run/samples chunks lack message indexes "
            "(format labrunner-3, written 2026-12-03/04; the Foxglove app's MCAP reader refuses them) in the "
            "current layout: the same records and samples, bit for bit, plus the indexes (16 bytes a sample). "
            "Each log is written beside the old one, fsynced, read back and compared, then renamed over it while "
            "the ledger records its new fingerprint; a crash loses nothing and the next run finishes the job. "
            "Refused while a runner holds DIR; a second run rewrites nothing."
        ),
        epilog="Exit status 1 when a log could not be rewritten (each is listed; it is left as it was).",
    )
    p.add_argument("directory", type=path_text, metavar="DIR", help="campaign directory")
    p.add_argument(
        "--dry-run", action="store_true", help="only say what would be rewritten and about how many bytes it adds"
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from labrunner.campaign.upgrade import dry_run, upgrade_logs

    directory = Path(args.directory)
    if args.dry_run:
        report = dry_run(directory)
    else:
        report = upgrade_logs(directory, progress=lambda line: print(line, file=sys.stderr, flush=True))
    print(f"upgrade-logs {directory}: {report.describe()}")
    for line in report.skipped:
        print(f"  skipped {line}")
    return 1 if report.skipped else 0
