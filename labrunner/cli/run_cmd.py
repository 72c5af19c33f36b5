"""``labrunner run FILE``: validate a campaign, create its directory and run every point."""

from __future__ import annotations

import argparse
import os
import sys

from labrunner.cli.argtypes import add_link_options, link_options, path_text, positive_int
from labrunner.errors import CampaignError, InvalidParameter


def add_execution_options(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``run`` and ``resume``."""
    parser.add_argument("--workers", type=positive_int, metavar="N", help="local worker processes (default: all cores)")
    parser.add_argument(
        "--executor", metavar="URL", help="run on a Dask distributed cluster, e.g. tcp://HOST:8786 (shared file system)"
    )
    parser.add_argument(
        "--batch-size", type=positive_int, metavar="N", help="runs per lockstep batch (default: automatic)"
    )
    add_link_options(parser)  # a real rig's link instead of its rig file's (kept for resume)
    parser.add_argument(
        "--live",
        nargs="?",
        const="",
        type=_live_text,
        metavar="[HOST:]PORT",
        help="serve the running campaign to the Foxglove app over WebSocket (default 127.0.0.1:8765; port 0: any "
        "free port); docs/live.md",
    )
    parser.add_argument(
        "--live-expose",
        action="store_true",
        help="allow --live on a non-loopback address (anyone who reaches it sees the campaign; no authentication)",
    )


def _live_text(text: str) -> str:
    """argparse type of ``--live``: PORT or HOST:PORT; a campaign file or directory given right
    after a bare ``--live`` is named as such (argparse would take it as the address)."""
    port = text.rpartition(":")[2]
    if not port.isdigit():
        raise argparse.ArgumentTypeError(
            f"must be a port 0-65535 or HOST:PORT, got {text!r} (a bare --live goes after the file or directory)"
        )
    return text


def execution_options(args: argparse.Namespace):
    """The runner's :class:`~labrunner.campaign.runner.Options` from the options of
    :func:`add_execution_options`."""
    from labrunner.campaign.live_view import parse_address
    from labrunner.campaign.runner import Options

    if args.live_expose and args.live is None:
        raise InvalidParameter("--live-expose", "needs --live HOST:PORT")
    live = parse_address(args.live, expose=args.live_expose) if args.live is not None else None
    return Options(
        workers=args.workers, executor=args.executor, batch_size=args.batch_size, live=live, link=link_options(args)
    )


def one_blas_thread() -> None:
    """A campaign runs one process per core (the runner and its workers), so BLAS threads of their
    own would only contend for those cores: numpy's OpenBLAS gets one thread per process (it reads
    the setting once, when numpy loads; a user's own setting is kept). A 1000-point motor campaign
    takes ~8 % less CPU; results are bit-identical (a lockstep batch's matrix-vector products split
    over runs, not over the sum)."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run a campaign file",
        description=(
            "Validate every point of a campaign file, create its directory (ledger, runs/) and run it. A guided "
            "campaign ([guided]) runs its tuning procedure in rounds, each next point chosen from the outcomes so far."
        ),
    )
    p.add_argument("file", type=path_text, metavar="FILE", help="campaign file (TOML), e.g. campaigns/quickstart.toml")
    p.add_argument("--out", type=path_text, metavar="DIR", help="campaign directory (default: data/<name>/)")
    add_execution_options(p)
    p.add_argument("--dry-run", action="store_true", help="print points, batches and an estimated time; create nothing")
    p.set_defaults(func=run)


def report(outcome, directory: str, command: str) -> int:
    """Print how a session ended; the exit code (0 done, 130 interrupted); raise if it stopped."""
    from labrunner.campaign.progress import format_counts

    print(f"{directory}: {format_counts(outcome.counts)} ({outcome.committed} runs in {outcome.elapsed_s:.1f} s)")
    _law_check_line(directory)
    if outcome.stop_reason:
        retry = (
            f" (`labrunner resume --retry-failed {directory}` reruns the failed points too)"
            if outcome.counts.get("failed", 0)
            else ""
        )
        raise CampaignError(f"stopped: {outcome.stop_reason}; continue with `labrunner resume {directory}`{retry}")
    if outcome.interrupted:
        if outcome.complete:
            print(f"labrunner {command}: interrupted after the last run: the campaign is complete", file=sys.stderr)
            return 0
        left = outcome.counts.get("planned", 0) + outcome.counts.get("claimed", 0)
        what = f"{left} of {sum(outcome.counts.values())} points left" if left else "its procedure has not finished"
        print(
            f"labrunner {command}: interrupted; {what}; continue with `labrunner resume {directory}`", file=sys.stderr
        )
        return 130
    return 0


def _law_check_line(directory: str) -> None:
    """A device-loop campaign's law check (docs/control-laws.md), on stderr when a run diverged."""
    from labrunner.campaign.status import law_check
    from labrunner.rigs.device.lawflag import DIVERGED, line

    law = law_check(directory)
    if law:
        print(line(law), file=sys.stderr if law[DIVERGED] else sys.stdout)


def run(args: argparse.Namespace) -> int:
    one_blas_thread()
    from labrunner.campaign.runner import start

    outcome, text = start(args.file, args.out, execution_options(args), dry=args.dry_run)
    if outcome is None:
        print(text)
        return 0
    return report(outcome, text, "run")
