"""argparse types whose errors name the allowed range, like every other bad input.

argparse reports a failed conversion as "invalid float value: 'x'"; :func:`numeric` says what the
option accepts instead ("argument --alpha: must be a number > -1, got 'x'"). The range itself is
checked by the library, which raises :class:`~labrunner.errors.InvalidParameter`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

_KIND_NAMES = {float: "a number", int: "an integer"}


def numeric(kind: type, allowed: str) -> Callable[[str], float | int]:
    """argparse ``type`` converting to ``kind`` (float or int); ``allowed`` (e.g. ``"> 0"``)
    completes the error "must be a number ...", resp. "must be an integer ..."."""

    def parse(text: str) -> float | int:
        try:
            return kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {_KIND_NAMES[kind]} {allowed}, got {text!r}") from None

    return parse


_integer_from_1 = numeric(int, ">= 1")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (a count of workers or runs)."""
    value = _integer_from_1(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def path_text(text: str) -> str:
    """argparse type: a file or directory path, not empty (``--out ""`` would otherwise mean the
    default directory, or the working directory, without a word)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must be a path, got {text!r}")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:  # bytes that are not UTF-8, carried as lone surrogates
        raise argparse.ArgumentTypeError(
            f"must be a path of valid UTF-8 (the ledger and the logs record paths as UTF-8 text), got {text!r}"
        ) from None
    return text


def add_link_options(parser: argparse.ArgumentParser) -> None:
    """``--port`` (serial) and ``--interface`` / ``--channel`` (CAN): the link a real rig file
    names, given here instead (``labrunner emulate`` prints the pty or the CAN channel)."""
    parser.add_argument("--port", metavar="DEV", help="serial port instead of the rig file's, e.g. /dev/pts/3")
    parser.add_argument("--interface", metavar="NAME", help="python-can interface instead of the rig file's")
    parser.add_argument("--channel", metavar="NAME", help="CAN channel instead of the rig file's")


def link_options(args: argparse.Namespace) -> dict[str, str | None]:
    """What :func:`add_link_options` parsed, for :func:`labrunner.rigs.config.load_rig_config`."""
    return {"port": args.port, "interface": args.interface, "channel": args.channel}
