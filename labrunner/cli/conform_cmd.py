"""``labrunner conform RIG.toml``: run the conformance vectors and the protocol's edge cases
against a device-loop device (docs/control-laws.md); non-zero exit when a check fails."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import add_link_options, link_options


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "conform",
        help="check a device-loop device against the conformance vectors and the protocol's edge cases",
        description="Handshake with the rig file's device, run every conformance vector of its rig kind in the "
        "sensor-table mode (the device reads y[k] from the run description: nothing moves), then the protocol's "
        "edge cases: descriptions it must REJECT (bad CRC-32, another version, bad magic, wrong length, unknown "
        "record, unknown kind, wrong channel counts), HELLO of another version, STOP and SAFE mid-run and the "
        "host-silence watchdog. Prints a pass/fail table; exit status 1 when a check fails.",
    )
    p.add_argument("rig", metavar="RIG.toml", help="a can or serial rig file")
    add_link_options(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--case", action="append", default=None, metavar="NAME", help="only this vector (repeatable)")
    p.add_argument("--no-protocol", action="store_true", help="run the vectors only")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import json

    from labrunner.errors import InvalidParameter
    from labrunner.rigs.config import load_rig_config
    from labrunner.rigs.device.conform import cases_for, conform, table

    config = load_rig_config(args.rig, link=link_options(args))
    if config.kind not in ("can", "serial"):
        raise InvalidParameter("rig.kind", f"conform checks can or serial rig files, got {config.kind!r}")
    known = cases_for(config.info.kind)
    for name in args.case or []:
        if name not in known:
            raise InvalidParameter(
                "--case", f"must be one of {', '.join(known)} for a {config.info.kind}, got {name!r}"
            )
    checks = conform(config, args.case, protocol=not args.no_protocol)
    passed = all(c.passed for c in checks)
    if args.json:
        print(json.dumps({"rig": str(args.rig), "passed": passed, "checks": [c.as_dict() for c in checks]}))
    else:
        print(table(checks))
    return 0 if passed else 1
