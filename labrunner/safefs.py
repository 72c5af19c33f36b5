"""Creating, rewriting and renaming files in a campaign directory without following a planted link.

A campaign directory may be shared: whoever can write into it can plant a symbolic link (or a FIFO,
a device) at a name the product writes, and a plain ``open(path, "w")`` or ``sqlite3.connect``
would then truncate or rewrite the file the link points to — another user's file. Every file the
product creates, rewrites or renames there goes through this module:

- :func:`open_fd` opens with ``O_NOFOLLOW`` and checks with ``fstat`` that what it opened is a
  regular file (a FIFO is opened non-blocking, then refused);
- :func:`temp_file` creates a temporary file under an unpredictable name with ``O_EXCL`` (through
  :func:`tempfile.mkstemp`, which adds ``O_NOFOLLOW``) in the target's own directory, so nothing
  can be planted at its name beforehand;
- :func:`replace` renames a finished temporary file over a name that holds a regular file or
  nothing (``rename`` would replace a link itself, not its target, but a link there means someone
  tampered with the directory: it is refused, not silently removed);
- :func:`check_regular` / :func:`check_directory` are the ``lstat`` checks for what is opened by a
  library that follows links (SQLite opens the ledger, its ``-wal``, ``-shm`` and ``-journal``).

Each refusal is a :class:`UnsafePath` naming the path and what was found there (exit 1).
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from labrunner.errors import CampaignError

#: The files SQLite opens beside a database (write-ahead log, shared memory, rollback journal).
SQLITE_SIDE_FILES = ("-wal", "-shm", "-journal")


class UnsafePath(CampaignError):
    """A name the product writes holds a symbolic link or another non-regular file."""


def _kind(mode: int) -> str:
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "not a regular file"


def _refuse(path: Path, mode: int, wanted: str = "a regular file") -> UnsafePath:
    return UnsafePath(
        f"{path} is {_kind(mode)}, not {wanted}: refusing to write through it (someone changed the "
        f"campaign directory; remove it after checking what it is)"
    )


def check_regular(path: Path) -> None:
    """Refuse ``path`` unless it is absent or a regular file (not followed if a link)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode):
        raise _refuse(path, st.st_mode)


def check_directory(path: Path) -> None:
    """Refuse ``path`` unless it is absent or a real directory (a link to one is refused)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(st.st_mode):
        raise _refuse(path, st.st_mode, "a directory")


def check_sqlite(path: Path) -> None:
    """Refuse a database whose file or any side file SQLite would open is not a regular file."""
    check_regular(path)
    for suffix in SQLITE_SIDE_FILES:
        check_regular(path.with_name(path.name + suffix))


def open_fd(path: Path, flags: int, mode: int = 0o644) -> int:
    """``os.open`` that never follows a final symbolic link and only returns a regular file's fd."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENXIO, errno.EISDIR):  # a link, a FIFO without reader, a directory
            raise _refuse(path, os.lstat(path).st_mode) from None
        raise
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise _refuse(path, st.st_mode)
    os.set_blocking(fd, True)
    return fd


def mkdir(path: Path, *, parents: bool = False) -> None:
    """Create directory ``path`` if absent (and its missing ``parents``); refuse a link or a file
    at its name."""
    if parents and path.parent != path and not path.parent.exists():
        mkdir(path.parent, parents=True)
    check_directory(path)
    with contextlib.suppress(FileExistsError):
        path.mkdir()
    check_directory(path)


def temp_file(directory: Path, prefix: str, suffix: str = "") -> tuple[int, Path]:
    """(fd, path) of a new, empty file under an unpredictable name in ``directory`` (O_EXCL, O_NOFOLLOW)."""
    check_directory(directory)
    fd, name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=directory)
    os.fchmod(fd, 0o644)  # mkstemp's 0600 would hide the campaign's files from its group
    return fd, Path(name)


@contextlib.contextmanager
def naming(path: Path) -> Iterator[None]:
    """An OSError without a file name (a write or fsync of an open file: ENOSPC, EIO) gets
    ``path``, so that the message says which file could not be written."""
    try:
        yield
    except OSError as exc:
        if exc.filename is None:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from exc
        raise


def replace(tmp: Path, final: Path) -> None:
    """Rename ``tmp`` over ``final``, which must be absent or a regular file."""
    check_regular(final)
    os.replace(tmp, final)


@contextlib.contextmanager
def atomic_path(final: Path, *, prefix: str | None = None) -> Iterator[Path]:
    """A fresh temporary path beside ``final`` to write to (by a library that opens by name);
    renamed over ``final`` when the block ends, removed if it raises. The file exists (empty,
    created O_EXCL) when the block starts, so the library truncates a file this process owns."""
    check_regular(final)
    fd, tmp = temp_file(final.parent, prefix or f".{final.name}.", ".tmp")
    os.close(fd)
    try:
        with naming(final):  # a full disk names the file it could not write
            yield tmp
        check_regular(tmp)  # still the file made above, not a link put in its place
        replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def write_atomic(final: Path, data: bytes, *, durable: bool = True) -> None:
    """Write ``data`` to ``final`` through a temporary file and a rename (fsynced if ``durable``)."""
    check_regular(final)
    fd, tmp = temp_file(final.parent, f".{final.name}.", ".tmp")
    try:
        with naming(final), os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
