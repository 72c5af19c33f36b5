"""``labrunner resume DIR``: continue a stopped, interrupted or crashed campaign."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import path_text
from labrunner.cli.run_cmd import add_execution_options, execution_options, one_blas_thread, report


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "resume",
        help="continue a campaign after a crash or Ctrl-C",
        description=(
            "Continue the campaign in DIR: terminal points are skipped, torn logs of interrupted runs are "
            "moved to DIR/quarantine/ and their points run again. Runs the campaign's own copy "
            "(DIR/campaign.toml), not the file it was started from. Refused while another runner holds DIR "
            "or when its rig file changed what would run."
        ),
    )
    p.add_argument(
        "directory", type=path_text, metavar="DIR", help="campaign directory (as given to or made by `labrunner run`)"
    )
    add_execution_options(p)
    p.add_argument("--retry-failed", action="store_true", help="run points that ended 'failed' again")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    one_blas_thread()
    from labrunner.campaign.runner import resume

    outcome, directory = resume(args.directory, execution_options(args), retry_failed=args.retry_failed)
    return report(outcome, directory, "resume")
