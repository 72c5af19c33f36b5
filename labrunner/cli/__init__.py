"""The ``labrunner`` command: a thin argparse front end over the library.

Each sub-command lives in its own module below ``labrunner.cli`` (``check-rig`` in
``check_rig_cmd``) and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``. Modules import
their heavy dependencies inside ``func`` so that ``labrunner --help`` stays fast.

One error boundary (:func:`main`): every failure is one line on stderr and an exit code — a usage
error (argparse's own, returned rather than raised as SystemExit; only ``--help`` and
``--version`` exit through it) or :class:`~labrunner.errors.InvalidParameter` (bad input: a file,
a flag, a campaign directory that is not one) exit 2; any other
:class:`~labrunner.errors.LabrunnerError` (a failed run or campaign) and an :class:`OSError` of the
environment (permissions, a full disk, a read-only or special file system; the message names the
path) exit 1; Ctrl-C exit 130. Anything else is a bug: one line
saying where its full traceback was written, exit 1. A reader that closes the pipe early
(``labrunner analyse DIR --json | head``) ends the command quietly, as in other tools.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import select
import signal
import sys
import tempfile
import traceback
from collections.abc import Sequence

from labrunner.errors import InvalidParameter, LabrunnerError, os_reason
from labrunner.interrupts import FirstPressStops
from labrunner.version import __version__

# Sub-command modules, in the order ``--help`` lists them.
COMMANDS = (
    "run",
    "resume",
    "status",
    "repair",
    "upgrade-logs",
    "analyse",
    "inspect",
    "plot",
    "identify",
    "bounds",
    "differentiator",
    "reproduce",
    "emulate",
    "check-rig",
    "vectors",
    "conform",
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
    if argv is None and signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # the program itself
        signal.signal(signal.SIGINT, FirstPressStops())
    try:
        return _main(argv)
    except KeyboardInterrupt:  # while the parser was built (imports) or the arguments parsed
        return _say("labrunner: interrupted", 130)
    finally:
        if argv is None:
            _exit_quickly()


def _exit_quickly() -> None:
    """Let the interpreter's teardown free objects by reference count only (the program itself,
    not a caller of :func:`main`): its garbage collections walk every object the command made
    (pandas, matplotlib, the frames), ~0.35 s of a 1000-run analysis (benchmarks/bench_campaign.py).
    Frozen objects are never walked; what they leave in cycles goes with the process's memory.
    Every log, table and the ledger are closed by then (each is written under a ``with``)."""
    gc.freeze()


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except _UsageError as exc:  # returned like every other bad input, not raised as SystemExit
        print(exc, file=sys.stderr)
        return 2
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    prefix = f"labrunner {args.command}: error:"
    if sys.stdout is None:  # started with stdout closed (`>&-`): say so before anything runs, not at its end
        return _say(f"{prefix} standard output is closed: run it with its output sent somewhere (> FILE)", 1)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not as a traceback at interpreter exit
        return code
    except InvalidParameter as exc:
        return _say(f"{prefix} {_line(exc)}", 2)
    except LabrunnerError as exc:
        return _say(f"{prefix} {_line(exc)}", 1)
    except KeyboardInterrupt:
        return _say(f"labrunner {args.command}: interrupted", 130)
    except BrokenPipeError:
        if not _reader_gone(sys.stdout):
            return _say(f"{prefix} {os_error(sys.exc_info()[1])}", 1)  # some other pipe broke
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no flush error at exit either
        return 141  # 128 + SIGPIPE, what a shell reports for a command killed by it
    except OSError as exc:
        return _say(f"{prefix} {_cwd_gone() or os_error(exc, args.command)}", 1)
    except UnicodeError as exc:
        if not _undecodable(exc):
            return _internal(args.command, argv, exc)
        return _say(f"{prefix} {_undecodable(exc)}", 2)
    except MemoryError:
        return _say(f"{prefix} out of memory", 1)
    except Exception as exc:  # a bug: one line here, the traceback in a file
        return _internal(args.command, argv, exc)


def _internal(command: str, argv: Sequence[str] | None, exc: Exception) -> int:
    where = _write_traceback(command, sys.argv[1:] if argv is None else list(argv))
    return _say(f"labrunner {command}: internal error: {_line(exc, type(exc).__name__)}; traceback in {where}", 1)


def _undecodable(exc: UnicodeError) -> str:
    """The one line for a file or folder name that is not UTF-8 (Python carries its bytes as lone
    surrogates, which the ledger's and the logs' UTF-8 text cannot hold); "" for another error."""
    text = getattr(exc, "object", None)
    if not isinstance(exc, UnicodeEncodeError) or not isinstance(text, str) or "surrogates" not in str(exc):
        return ""
    # the name holding the bad bytes: the run of text around them up to a quote, space or comma
    start, end = exc.start, exc.end
    while start > 0 and text[start - 1] not in "\"' ,:{}[]":
        start -= 1
    while end < len(text) and text[end] not in "\"' ,:{}[]":
        end += 1
    return (
        f"the name {text[start:end]!r} is not valid UTF-8 (the ledger and the logs record names as UTF-8 "
        "text): rename the file or folder"
    )


def _cwd_gone() -> str:
    """The one line for a command run from a working directory deleted since; "" if it exists."""
    try:
        os.getcwd()
    except FileNotFoundError:
        return "the working directory no longer exists (deleted since this shell entered it): cd to an existing one"
    return ""


def os_error(exc: OSError, command: str = "") -> str:
    """One line for an environment failure, naming the path: "PATH: No space left on device"
    (the advice for ``command``, see :func:`~labrunner.errors.os_reason`)."""
    reason = os_reason(exc, command=command)
    paths = [p for p in (exc.filename, exc.filename2) if p is not None]
    return ": ".join([*map(str, paths), reason]) if paths else reason


def _line(exc: BaseException, kind: str = "") -> str:
    """The exception's message on one line (newlines folded), led by ``kind`` when given."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{kind}: {text}" if kind else text


def _say(line: str, code: int) -> int:
    try:
        print(line, file=sys.stderr)
    except OSError:  # stderr itself is gone: the exit code still tells
        pass
    return code


def _write_traceback(command: str, argv: list[str]) -> str:
    """Write the current exception's traceback to a fresh file; return its path (or why not)."""
    try:
        fd, path = tempfile.mkstemp(prefix=f"labrunner-{command}-", suffix=".traceback.txt")
        # a name that is not UTF-8 is written as its escapes: this handler must not fail itself
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace") as fh:
            fh.write(f"labrunner {' '.join(argv)}\n\n{traceback.format_exc()}")
        return path
    except OSError as exc:
        return f"(not written: {exc.strerror})"


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
