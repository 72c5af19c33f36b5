"""``labrunner status DIR``: where a campaign stands (reads only; safe while it runs)."""

from __future__ import annotations

import argparse
import json

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "status",
        help="counts of a campaign's points by outcome, elapsed time and an estimate",
        description=(
            "Show a campaign's points by outcome (completed, no-motion, aborted, failed; claimed and planned "
            "for points not run yet), its elapsed time and an estimate of the time left."
        ),
    )
    p.add_argument("directory", type=path_text, metavar="DIR", help="campaign directory")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _clock(seconds: float | None) -> str:
    if seconds is None:
        return "unknown"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def run(args: argparse.Namespace) -> int:
    from labrunner.campaign.progress import format_counts
    from labrunner.campaign.rig_timing import timing_line
    from labrunner.campaign.status import status

    st = status(args.directory)
    if args.json:
        print(json.dumps(st, sort_keys=True))
        return 0
    runner = f"running (host {st['running']['host']} PID {st['running']['pid']})" if st["running"] else "not running"
    print(f"campaign {st['campaign']} in {st['directory']}: {runner}")
    print(f"  {st['total']} points: {format_counts(st['outcomes'])}; quarantined files: {st['quarantined']}")
    rate = f"{st['rate_per_s']:.2f} runs/s" if st["rate_per_s"] else "no rate yet"
    print(
        f"  elapsed {_clock(st['elapsed_s'])} over {st['sessions']} session(s), {rate}, estimated {_clock(st['estimate_s'])} left"
    )
    if "law_check" in st:  # device-loop runs: did the device run the law?
        from labrunner.rigs.device.lawflag import line

        print(f"  {line(st['law_check'])}")
    if "timing" in st:
        print("  " + timing_line(st["timing"]))
    if "guided" in st:  # what the procedure decided so far
        from labrunner.campaign.guided_run import status_lines

        print("\n".join(status_lines(st["guided"])))
    return 0
