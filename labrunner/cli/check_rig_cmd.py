"""``labrunner check-rig RIG.toml``: handshake, round trips, error counters and link load of a real rig."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import add_link_options, link_options, positive_int


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "check-rig",
        help="handshake a can/serial rig, time round trips, show error counters, link load and the host loop's highest f_s",
        description="Open a can or serial rig file's link, handshake with the device (protocol version, device kind, "
        "channels, max f_s, capabilities, firmware id), time N HEARTBEAT round trips, and report the "
        "error counters, the link load of both loop placements and the highest f_s the host loop "
        "sustains with margin. Nothing moves (no run is set up) unless --dead-time asks for a small input step.",
    )
    p.add_argument("rig", metavar="RIG.toml", help="a can or serial rig file")
    add_link_options(p)
    p.add_argument("--pings", type=positive_int, default=200, metavar="N", help="round trips to time (default 200)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--campaign",
        metavar="C.toml",
        help="count the device loop's stream for this campaign's first point (every logged column, at its f_s)",
    )
    p.add_argument(
        "--dead-time",
        action="store_true",
        help="MOVES THE RIG: a small open-loop input step under the rig file's safety routine; compares the delay "
        "from input to measured motion with the twin's and the rig file's declared delay",
    )
    p.add_argument(
        "--step",
        type=float,
        default=None,
        metavar="U",
        help="the dead-time step's input level (default: 10%% of the input range above the safe input)",
    )
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import json

    from labrunner.errors import InvalidParameter
    from labrunner.rigs.config import load_rig_config
    from labrunner.rigs.transports.checkrig import check_rig, describe

    config = load_rig_config(args.rig, link=link_options(args))
    if config.kind not in ("can", "serial"):
        raise InvalidParameter("rig.kind", f"check-rig checks can or serial rig files, got {config.kind!r}")
    if args.step is not None and not args.dead_time:
        raise InvalidParameter("--step", "sets the --dead-time step; give --dead-time too")
    report = check_rig(config, args.pings, args.campaign, args.dead_time, args.step)
    print(json.dumps(report, sort_keys=True) if args.json else "\n".join(describe(report)))
    _remember(args.rig, config, report["max_host_fs"])
    return 1 if report.get("dead_time", {}).get("verdict") in ("late", "early") else 0


def _remember(rig: str, config, max_host_fs: float) -> None:
    """Keep what the link sustains, for `run` to warn before a faster campaign (link_record)."""
    import sys

    from labrunner.rigs.config import resolve_rig_file
    from labrunner.rigs.transports import link_record

    try:
        link_record.remember(link_record.link_key(resolve_rig_file(rig), config.kind, config.parameters), max_host_fs)
    except OSError as exc:
        print(f"note: could not keep the measurement in {link_record.record_path()}: {exc.strerror}", file=sys.stderr)
