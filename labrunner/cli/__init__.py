"""The ``labrunner`` command: a thin argparse front end over the library.

Each sub-command lives in its own module below ``labrunner.cli`` (``check-rig`` in
``check_rig_cmd``) and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``. Modules import
their heavy dependencies inside ``func`` so that ``labrunner --help`` stays fast.

Errors: a usage error (argparse's own) or :class:`~labrunner.errors.InvalidParameter` → one line
on stderr, exit 2 (``main`` returns it; only ``--help`` and ``--version`` exit through SystemExit);
any other :class:`~labrunner.errors.LabrunnerError` → one line, exit 1. A reader that closes the
pipe early (``labrunner analyse DIR --json | head``) ends the command quietly, as in other tools.
"""

from __future__ import annotations

import argparse
import importlib
import os
import select
import sys
from collections.abc import Sequence

from labrunner import __version__
from labrunner.errors import InvalidParameter, LabrunnerError

# Sub-command modules, in the order ``--help`` lists them.
COMMANDS = (
    "run",
    "resume",
    "status",
    "analyse",
    "inspect",
    "plot",
    "identify",
    "bounds",
    "differentiator",
    "reproduce",
    "emulate",
    "check-rig",
)


class _UsageError(Exception):
    """A bad option or argument, as argparse words it (``main`` prints it and returns 2)."""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line and exit 2, like every bad input."""

    def error(self, message: str) -> None:  # noqa: D401 - argparse API
        raise _UsageError(f"{self.prog}: error: {message}")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="labrunner",
        description=(
            "Run parameter campaigns of model-free control on lab rigs or their simulated twins, "
            "resume them after a crash, and turn the logged runs into maps."
        ),
    )
    parser.add_argument("--version", action="version", version=f"labrunner {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"labrunner.cli.{name.replace('-', '_')}_cmd").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:  # returned like every other bad input, not raised as SystemExit
        print(exc, file=sys.stderr)
        return 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not as a traceback at interpreter exit
        return code
    except InvalidParameter as exc:
        print(f"labrunner {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except LabrunnerError as exc:
        print(f"labrunner {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"labrunner {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        if not _reader_gone(sys.stdout):
            raise  # some other pipe broke: a real error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error at exit either
        return 141  # 128 + SIGPIPE, what a shell reports for a command killed by it


def _reader_gone(stream) -> bool:
    """Whether ``stream`` is a pipe whose reading end is closed (poll reports an error on it)."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (e.g. captured in tests)
        return False
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
