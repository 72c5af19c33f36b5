"""The session journal: what lets ``resume`` after a crash settle only the points that were running.

A session starts changing a campaign directory only once the directory is settled and checked: a
new ledger (``run``), a sealed directory (:mod:`.seal`), or one that ``resume`` checked row by row
and settled (:mod:`.recovery`). From then on only the session changes it, and only so:

- the ledger, by transactions (SQLite: each whole or not at all, also when the process is killed):
  points planned → claimed → finished, claimed → planned, finished → planned (retries), a guided
  campaign's new points;
- ``runs/``, by its workers: a claimed point's log is written as ``.tmp-<id>-…`` and renamed into
  place (fsynced) before its row is committed.

So after the session's process dies with the machine still up, what is unsettled is its claimed
points (each with a published log, a temporary one, or none), and the checks that read every row
(:mod:`.integrity`) would find what they found when the session began. The journal, a ``meta``
entry written when the session starts (:func:`begin`) and kept by every transaction that moves
points between states (:attr:`~labrunner.campaign.ledger.Ledger.on_moved`, in that transaction), holds:

- the machine's boot id (Linux ``/proc/sys/kernel/random/boot_id``) and host name: another one
  means the machine went down since (a power cut may lose the last transactions, but not the logs
  the workers fsynced: a planned point may then have a published log) or another machine resumes;
- the number of points in each state as the last transaction left them: a ledger changed since
  by anything else (another tool, an older labrunner) no longer matches (the seal's own test).

:func:`holds` compares both (one read of ``/proc``; the counts ``resume`` reads anyway). When it
holds, ``resume`` settles the claimed points only (:func:`labrunner.campaign.recovery.settle_running`:
a ``stat`` each) instead of listing ``runs/`` and reading every row. Left unchecked until the
resumed session ends — whose end-of-session check (:func:`labrunner.campaign.seal.seal`: every
check, one listing) runs before anything is sealed — is what no crash of the session causes: a log
deleted by hand, a file dropped into ``runs/``, the ledger file damaged on disk since its last
check; and the claimed points' temporary logs wait there to be quarantined. A session that ends
cleanly removes the journal (:func:`end`): the seal then vouches for the directory or, if the
end-of-session check failed, nothing does and the next ``resume`` checks everything.
"""

from __future__ import annotations

import json
import socket
import sqlite3
from collections.abc import Mapping
from pathlib import Path

from labrunner.campaign.ledger import Ledger

#: The ledger ``meta`` key holding the journal (JSON).
META_KEY = "session_journal"

#: Changes at every boot of a Linux machine; elsewhere absent, and no journal is kept.
BOOT_ID = Path("/proc/sys/kernel/random/boot_id")


def _machine() -> dict[str, str] | None:
    """This machine's boot id and host name; None where there is no boot id."""
    try:
        boot = BOOT_ID.read_text().strip()
    except OSError:
        return None
    return {"boot": boot, "host": socket.gethostname()} if boot else None


def begin(ledger: Ledger, counts: Mapping[str, int]) -> None:
    """The directory is settled and checked, its states ``counts``, and this session is about to
    change it: write the journal, and keep it in every transaction from now on."""
    machine = _machine()
    ledger.on_moved = None
    ledger.set_meta(META_KEY, None if machine is None else json.dumps({**machine, "counts": dict(counts)}))
    if machine is not None:
        ledger.on_moved = lambda delta: _move(ledger.db, delta)


def _move(db: sqlite3.Connection, delta: Mapping[str, int]) -> None:
    """Within the transaction that moved them: add ``delta`` to the journal's counts (read and
    written in the transaction, so a rolled-back one leaves them as they were)."""
    row = db.execute("SELECT value FROM meta WHERE key = ?", (META_KEY,)).fetchone()
    if row is None:  # removed behind the session's back: it no longer holds, whatever it says
        return
    journal = json.loads(row[0])
    counts = journal["counts"]
    for state, n in delta.items():
        counts[state] = counts.get(state, 0) + n
    db.execute("UPDATE meta SET value = ? WHERE key = ?", (json.dumps(journal), META_KEY))


def _stored(ledger: Ledger) -> dict | None:
    """The journal, if one was written on this machine since its last boot."""
    machine = _machine()
    try:
        stored = json.loads(ledger.meta().get(META_KEY) or "null")
    except ValueError:
        return None
    if machine is None or not isinstance(stored, dict) or not isinstance(stored.get("counts"), dict):
        return None
    return stored if all(stored.get(k) == v for k, v in machine.items()) else None


def kept(ledger: Ledger) -> bool:
    """Whether a journal of this machine since its boot is kept (the counts not compared: a first
    look, before the lock, at whether :func:`holds` is likely)."""
    return _stored(ledger) is not None


def holds(ledger: Ledger, counts: Mapping[str, int]) -> bool:
    """Whether the ledger keeps a journal of a session of this machine since its last boot, whose
    counts are the points' states ``counts`` now (:meth:`~labrunner.campaign.ledger.Ledger.counts`)."""
    stored = _stored(ledger)
    return stored is not None and {k: v for k, v in stored["counts"].items() if v} == {
        k: v for k, v in counts.items() if v
    }


def end(ledger: Ledger) -> bool:
    """The session ended cleanly: remove the journal, whichever machine wrote it (the end-of-session
    check and the seal follow); return whether there was one."""
    ledger.on_moved = None
    if META_KEY not in ledger.meta():
        return False
    ledger.set_meta(META_KEY, None)
    return True
