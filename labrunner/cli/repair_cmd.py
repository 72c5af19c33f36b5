"""``labrunner repair DIR``: rebuild a damaged or deleted ledger from the campaign copy and the logs."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "repair",
        help="rebuild a campaign's damaged or deleted ledger from its campaign copy and published logs",
        description=(
            "Rebuild DIR/ledger.sqlite: the grid from DIR/campaign.toml, every complete published log in "
            "DIR/runs/ as its point's finished row, failed points and the session history from the old ledger "
            "as far as it can be read, everything else planned. The old ledger is moved to DIR/quarantine/. "
            "Then `labrunner resume DIR` runs what is left."
        ),
    )
    p.add_argument("directory", type=path_text, metavar="DIR", help="campaign directory")
    p.add_argument(
        "--campaign",
        metavar="FILE",
        help="the original campaign file, when its rig is a path relative to it and the old ledger is lost",
    )
    p.add_argument("--force", action="store_true", help="rebuild a ledger that passes every integrity check too")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    from labrunner.campaign.repair import repair

    report = repair(args.directory, campaign_file=args.campaign, force=args.force)
    print(f"repair {args.directory}: {report.describe()}")
    for line in report.rejected:
        print(f"  unusable log {line}")
    print(f"continue with `labrunner resume {args.directory}`")
    return 0
