"""The seal: proof, kept in the ledger, that a campaign directory needs no settling on ``resume``.

Settling a crash (:mod:`labrunner.campaign.recovery`) has to list ``runs/`` and compare every
finished point's log with the ledger: ~2 s at 10^6 points, as long again for the checks that read
every ledger row (:mod:`labrunner.campaign.integrity`). A session that ends cleanly does both once
(:func:`seal`) and, if the directory is consistent, writes into ``meta``:

- ``runs/``'s device, inode and modification time [ns]: the kernel updates a directory's mtime
  whenever an entry in it is created, deleted or renamed, so an unchanged mtime means the same
  set of names — no log deleted or added, no torn ``.tmp-`` file left — since the seal;
- the number of points in each state, nothing ``claimed``.

``resume`` then checks the seal (:func:`holds`: one ``stat`` and the states' counts, which it
reads anyway: ~0.1 s at 10^6 points) instead of settling: every finished point's log is there, no unfinished point has a
published log, no torn file waits to be quarantined, no point is claimed. Anything that may change
the ledger or ``runs/`` clears the seal first (:func:`clear`), so a crash leaves none; the next
``resume`` settles and checks everything as before, or, where the crashed session's journal
holds (:mod:`.journal`), settles its running points and leaves the rest to this check at the end.

Timestamps are coarse (a kernel tick): a deletion in the same tick as the seal's ``stat`` would
keep the mtime. :func:`seal` therefore reads the mtime, waits :data:`TICK_S` and only then lists
``runs/``: a change before the listing is in the listing, a change after it has a later mtime.
(On a network file system this holds as far as its attribute caching lets a client see the
server's mtime.)
"""

from __future__ import annotations

import json
import os
import sqlite3
import time

from labrunner.campaign import integrity
from labrunner.campaign.ledger import TERMINAL, Ledger
from labrunner.campaign.worker import RUNS_DIR, TMP_PREFIX, final_path

#: The ledger ``meta`` key holding the seal (JSON).
META_KEY = "runs_seal"

#: Longer than a file-system timestamp tick (1–10 ms on Linux: the kernel's coarse clock) [s].
TICK_S = 0.02


def _runs_stat(ledger: Ledger) -> dict[str, int] | None:
    """``runs/``'s device, inode and mtime; None if there is none, or if its file system keeps
    whole milliseconds or coarser (FAT: 2 s), whose ticks :data:`TICK_S` does not outlast."""
    try:
        st = os.stat(ledger.directory / RUNS_DIR)
    except OSError:
        return None
    if st.st_mtime_ns % 1_000_000 == 0:
        return None
    return {"dev": st.st_dev, "ino": st.st_ino, "mtime_ns": st.st_mtime_ns}


def _stored(ledger: Ledger) -> dict | None:
    try:
        stored = json.loads(ledger.meta().get(META_KEY) or "null")
    except ValueError:
        return None
    return stored if isinstance(stored, dict) and stored.get("runs") == _runs_stat(ledger) else None


def runs_unchanged(ledger: Ledger) -> bool:
    """Whether the ledger keeps a seal and ``runs/`` is as it was then (the points' states not
    compared: a first look, before the lock, at whether :func:`holds` is likely)."""
    return _stored(ledger) is not None


def holds(ledger: Ledger, counts: dict[str, int]) -> bool:
    """Whether the ledger keeps a seal that still describes ``runs/`` and the points' states
    ``counts`` (:meth:`~labrunner.campaign.ledger.Ledger.counts`, read by the caller)."""
    stored = _stored(ledger)
    return stored is not None and counts.get("claimed", 0) == 0 and stored.get("counts") == counts


def clear(ledger: Ledger) -> None:
    """Remove the seal: the ledger or ``runs/`` is about to change."""
    ledger.set_meta(META_KEY, None)


def listing(ledger: Ledger) -> tuple[dict[str, int] | None, set[str]]:
    """``runs/``'s stat, then — :data:`TICK_S` later, so that any later change of ``runs/`` gets a
    later mtime (module docstring) — the names in it (None and nothing if there is no ``runs/``)."""
    before = _runs_stat(ledger)
    if before is None:
        return None, set()
    time.sleep(TICK_S)
    try:
        return before, {entry.name for entry in os.scandir(ledger.directory / RUNS_DIR)}
    except OSError:
        return None, set()


def has_temporary(names: set[str]) -> bool:
    """Whether ``names`` holds a temporary log's (``.tmp-…``): one search of the joined names, not a
    test a name (half the time at 10^6 names)."""
    return f"\n{TMP_PREFIX}" in "\n" + "\n".join(names)


def log_rows(ledger: Ledger) -> sqlite3.Cursor:
    """Every point's (id, state, log_path), in table order, as plain tuples (a Row object a point
    costs ~30 % more of a pass over 10^6 rows)."""
    cursor = ledger.db.cursor()
    cursor.row_factory = None
    return cursor.execute("SELECT id, state, log_path FROM points")


def consistent(ledger: Ledger, names: set[str]) -> bool:
    """Whether ``runs/`` (its ``names``) holds every finished point's log, no published log of an
    unfinished point and no ``.tmp-`` file, nothing is claimed, and the ledger passes every check.
    One pass over the rows, streamed."""
    if ledger.counts().get("claimed", 0):
        return False
    # on a read-only connection of its own: the checks that read every row take ~40 % less CPU
    # there than on the writing one (5.5 → 3.4 s at 10^6 points, measured)
    with Ledger.open_readonly(ledger.directory, verify=False) as reader:
        if integrity.problem(reader.db, thorough=True):
            return False
    if has_temporary(names):
        return False
    prefix = f"{RUNS_DIR}/"
    for pid, state, log_path in log_rows(ledger):
        if state in TERMINAL:
            if log_path and not (
                log_path[len(prefix) :] in names
                if log_path.startswith(prefix)
                else (ledger.directory / log_path).exists()
            ):
                return False  # a finished run's log is missing
        elif final_path(pid)[len(prefix) :] in names:
            return False  # a published log its row does not record
    return True


def adopt(ledger: Ledger, before: dict[str, int] | None) -> bool:
    """Write the seal for a directory found consistent from a :func:`listing` that read ``before``:
    only if ``runs/`` is still as it was then and nothing is claimed; return whether it did."""
    counts = ledger.counts()
    if before is None or counts.get("claimed", 0) or _runs_stat(ledger) != before:
        return False
    ledger.set_meta(META_KEY, json.dumps({"runs": before, "counts": counts}, sort_keys=True))
    return True


def seal(ledger: Ledger, counts: dict[str, int] | None = None) -> bool:
    """Check the directory (:func:`consistent`) and, if it is consistent, write the seal; return
    whether it did. A seal that still holds (``counts``: the states now, if the caller has them)
    is kept without listing ``runs/`` again."""
    if holds(ledger, ledger.counts() if counts is None else counts):
        return True
    clear(ledger)
    before, names = listing(ledger)
    return before is not None and consistent(ledger, names) and adopt(ledger, before)
