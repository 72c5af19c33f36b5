"""``labrunner vectors --out DIR``: the device loop's conformance vectors (docs/control-laws.md)."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "vectors",
        help="write the device loop's conformance vectors: per case a run description, y[k] → expected rows, verdict",
        description="Write one directory per case under DIR: description.bin (the run description a device receives, "
        "with y[k] as its SENSOR_TABLE), description.txt (the same, readable), vector.csv (k, then the logged "
        "columns: the measured outputs are y[k], every other column the expected value) and verdict.txt. "
        "The cases cover every controller kind the device loop accepts (docs/control-laws.md).",
    )
    p.add_argument("--out", required=True, type=path_text, metavar="DIR", help="directory to write the vectors into")
    p.add_argument("--case", action="append", default=[], metavar="NAME", help="only this case (repeatable)")
    p.set_defaults(func=main)


def main(args: argparse.Namespace) -> int:
    import os

    from labrunner.errors import InvalidParameter
    from labrunner.rigs.device.vectors import CASES, write

    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise InvalidParameter("--out", f"{args.out!r} exists and is not a directory")
    for name in args.case:
        if name not in CASES:
            raise InvalidParameter("--case", f"must be one of {', '.join(CASES)}, got {name!r}")
    for folder in write(args.out, args.case or None):
        print(folder)
    return 0
