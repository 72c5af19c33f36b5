"""Reading a user's input file (a campaign, a rig file) safely: a regular file of bounded size, TOML
of bounded nesting. A FIFO or a device (``/dev/zero``, a terminal) would block or never end, a
huge file would fill the memory, and arrays nested a thousand deep overflow Python's recursion in
the parser or, worse, later in a run; each is refused here with a one-line
:class:`~labrunner.errors.InvalidParameter` before anything is created."""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path
from typing import Any

from labrunner.errors import InvalidParameter

MAX_BYTES = 4 * 2**20  # a campaign of 10^4 explicit points is ~1 MiB
MAX_NESTING = 32  # tables and arrays inside each other; the shipped files use at most 4


def read_text(path: str | os.PathLike, field: str, what: str) -> str:
    """The UTF-8 text of the regular file ``path`` (at most :data:`MAX_BYTES`); ``field`` and
    ``what`` ("campaign file") name it in the error."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InvalidParameter(field, f"{what} {str(path)!r} does not exist") from None
    except OSError as exc:
        raise InvalidParameter(field, f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(info.st_mode):
        kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file (a FIFO, socket or device)"
        raise InvalidParameter(field, f"{what} {str(path)!r} is {kind}")
    if info.st_size > MAX_BYTES:
        raise InvalidParameter(field, f"{what} {str(path)!r} has {info.st_size} bytes; at most {MAX_BYTES}")
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_BYTES + 1)
    except OSError as exc:
        raise InvalidParameter(field, f"cannot read {str(path)!r}: {exc.strerror or exc}") from None
    if len(data) > MAX_BYTES:  # grew since stat
        raise InvalidParameter(field, f"{what} {str(path)!r} has more than {MAX_BYTES} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InvalidParameter(
            field, f"{what} {str(path)!r} is not UTF-8 text ({exc.reason} at byte {exc.start})"
        ) from None


def loads_toml(text: str, field: str, prefix: str = "") -> dict[str, Any]:
    """TOML text → dict; a syntax error or nesting deeper than :data:`MAX_NESTING` is one
    :class:`InvalidParameter` on ``field`` naming the line, or on ``prefix`` + the key."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidParameter(field, f"is not valid TOML: {exc}") from None
    except RecursionError:
        raise InvalidParameter(field, f"nests arrays or tables too deeply (at most {MAX_NESTING} levels)") from None
    stack: list[tuple[str, Any, int]] = [("", doc, 0)]
    while stack:  # iterative: the check itself must not recurse
        key, node, depth = stack.pop()
        if depth > MAX_NESTING:
            raise InvalidParameter(
                f"{prefix}{key}" if key else field, f"nests arrays or tables {depth} levels deep; at most {MAX_NESTING}"
            )
        if isinstance(node, dict):
            stack.extend((f"{key}.{k}" if key else k, v, depth + 1) for k, v in node.items())
        elif isinstance(node, list):
            stack.extend((key, v, depth + 1) for v in node)
    return doc
