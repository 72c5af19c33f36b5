"""One runner per campaign directory: an ``flock`` on ``DIR/.lock`` that names its holder.

The kernel drops an ``flock`` when its holder dies, however it dies (SIGKILL included), so a
lock left by a dead runner is stale by construction and the next runner takes it over; the file's
content (host, PID, start time, and the runner's latest progress: :meth:`DirectoryLock.publish`)
only serves the messages and ``status``. While a live runner holds it, a second
one is refused with the holder's host and PID. A holder recorded on another host cannot be
checked by PID, but ``flock`` is authoritative on local disks and NFSv4 alike, so the record is
only reported, never trusted over the lock itself.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import time
from dataclasses import dataclass
from pathlib import Path

from labrunner import safefs
from labrunner.errors import CampaignError

LOCK_NAME = ".lock"
_TRIES = 5


@dataclass(frozen=True)
class Holder:
    host: str
    pid: int
    started_at: float
    command: str = ""
    progress: dict | None = None  # the runner's rate and ETA as it last showed them (DirectoryLock.publish)

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started_at))
        return f"host {self.host} PID {self.pid} (`labrunner {self.command}` since {when})"


def _read(fd: int) -> Holder | None:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = os.read(fd, 4096)
    try:
        d = json.loads(raw)
        progress = d.get("progress")
        return Holder(
            str(d["host"]),
            int(d["pid"]),
            float(d["started_at"]),
            str(d.get("command", "")),
            progress if isinstance(progress, dict) else None,
        )
    except (ValueError, KeyError, TypeError, AttributeError):
        return None


class DirectoryLock:
    """Hold the campaign directory's lock; ``took_over`` names a stale holder that was replaced."""

    def __init__(self, directory: Path, command: str) -> None:
        self.path = directory / LOCK_NAME
        self.command = command
        self.fd: int | None = None
        self.took_over: Holder | None = None

    def acquire(self) -> DirectoryLock:
        fd = safefs.open_fd(self.path, os.O_RDWR | os.O_CREAT)  # never through a planted link
        for attempt in range(_TRIES):  # `status` holds a shared lock for a moment: retry briefly
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if attempt == _TRIES - 1:
                    holder = _read(fd)
                    os.close(fd)
                    who = holder.describe() if holder else "another process"
                    raise CampaignError(
                        f"{self.path.parent} is in use by {who}; wait for it or stop it first"
                    ) from None
                time.sleep(0.02)
        previous = _read(fd)  # a record left behind: its holder died without releasing
        if previous and previous.pid != os.getpid():
            self.took_over = previous
        here = socket.gethostname()
        me = Holder(here, os.getpid(), time.time(), self.command)
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me.__dict__).encode(), 0)
        os.fsync(fd)
        self.fd, self._me = fd, me
        return self

    def publish(self, progress: dict) -> None:
        """Add the runner's progress (rate, ETA, …) to the holder record, for ``status`` from another
        terminal: written in place (no new file), not fsynced (it is advice, renewed every second or
        so); a reader that catches it half-written sees no JSON and falls back to the ledger."""
        if self.fd is None:
            return
        data = json.dumps({**self._me.__dict__, "progress": progress}).encode()
        os.pwrite(self.fd, data, 0)
        os.ftruncate(self.fd, len(data))

    def release(self) -> None:
        """Clear the holder record and drop the lock (the file stays: unlinking it would race)."""
        if self.fd is not None:
            os.ftruncate(self.fd, 0)
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> DirectoryLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def holder(directory: Path) -> Holder | None:
    """The live holder of ``directory``'s lock, or None if nobody runs it (reads only)."""
    path = directory / LOCK_NAME
    try:
        fd = safefs.open_fd(path, os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read(fd) or Holder("?", 0, 0.0)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
