"""Checking a campaign ledger before ``status``, ``resume`` or ``analyse`` trusts it.

:func:`verify` says exactly what is wrong, in one line, or returns quietly:

- not an SQLite database, or one that fails ``PRAGMA quick_check`` (truncated, overwritten);
- not a labrunner ledger (tables or columns missing, another schema version, meta keys missing);
- point rows missing or added: the row count against the planned count kept in ``meta``, the grid
  order ``seq`` = 0…n−1, and the checksum of the point ids in grid order written at creation;
- a row whose parameters are not a JSON object, or were changed since planned (the checksum of
  every row's id and parameters written at creation, kept as a guided campaign adds rounds).

The checks that read every row (``quick_check``, the ids' checksum, the parameters' JSON) take
~1 s per 10^5 points; a reader that reads every row anyway (the results table) leaves the ids' and
parameters' checks to :class:`RowDigests` over the rows it reads (``per_row=False``), once; ``status`` (reads only, and must answer in well under a second at 10^6
points) runs them only up to 20 000 points and above runs the others — structure, meta, row count
and grid order, all from the schema and the primary key — with ``thorough=False``; ``analyse`` and
``repair`` run them all, ``resume`` too unless the directory is sealed (:mod:`.seal`: they ran when
its last session ended, and nothing changed since) or, after a crash, its session journal holds
(:mod:`.journal`: they ran before the crashed session began, and only it changed the ledger
since); then they run when the resumed session ends, before it is sealed.

Each problem names the file and ends with the way out: ``labrunner repair DIR`` rebuilds the
ledger from the campaign copy and the published logs (:mod:`labrunner.campaign.repair`).
``resume`` also compares the ids with the stored campaign re-planned (:func:`check_plan`).
"""

from __future__ import annotations

import hashlib
import sqlite3
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from labrunner.errors import InvalidParameter

SCHEMA_VERSION = "1"  # of the ledger's tables; the ledger writes it into ``meta``
TABLES = ("meta", "points", "quarantine", "sessions")
POINT_COLUMNS = ("seq", "id", "parameters", "batch_key", "state", "outcome", "outcome_json", "log_path", "attempts")
META_KEYS = ("schema_version", "campaign", "points")  # resume also needs campaign_file and plan_checksum


class LedgerDamaged(InvalidParameter):
    """The ledger cannot be trusted; the message says why and how to rebuild it (exit 2)."""

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return (type(self), (self.field, self.message))


def damaged(path: Path, problem: str) -> LedgerDamaged:
    directory = path.parent
    return LedgerDamaged(
        str(path),
        f"{problem}; rebuild it from the campaign copy and the published logs with `labrunner repair {directory}`",
    )


def problem(db: sqlite3.Connection, *, thorough: bool = True, per_row: bool = True) -> str:
    """What is wrong with the ledger open in ``db`` ("" if nothing); ``thorough=False`` skips the
    checks that read every row (see the module), ``per_row=False`` those of the ids and parameters
    (the caller runs :class:`RowDigests` over every row it reads)."""
    try:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        missing = [t for t in TABLES if t not in tables]
        if missing:
            return f"is not a labrunner ledger (no table {', '.join(missing)})"
        columns = {r[1] for r in db.execute("PRAGMA table_info(points)")}
        lacking = [c for c in POINT_COLUMNS if c not in columns]
        if lacking:
            return f"is not a labrunner ledger (table points lacks {', '.join(lacking)})"
        check = [r[0] for r in db.execute("PRAGMA quick_check(3)")] if thorough else ["ok"]
        if check != ["ok"]:
            return f"is damaged (SQLite quick_check: {'; '.join(check)})"
        meta = {r[0]: r[1] for r in db.execute("SELECT key, value FROM meta")}
        absent = [k for k in META_KEYS if k not in meta]
        if absent:
            return f"is not a labrunner ledger (meta lacks {', '.join(absent)})"
        if meta["schema_version"] != SCHEMA_VERSION:
            return f"has ledger schema {meta['schema_version']!r}, this labrunner reads {SCHEMA_VERSION!r}"
        return _rows(db, meta, thorough and per_row)
    except sqlite3.DatabaseError as exc:
        return f"is not a readable ledger ({exc})"


def _rows(db: sqlite3.Connection, meta: dict[str, str], thorough: bool) -> str:
    try:
        planned = int(meta["points"])
    except ValueError:
        return f"is damaged (meta points = {meta['points']!r} is not a count)"
    # three subqueries: SQLite then counts from the b-tree pages and finds the ends from the key
    # (20 ms at 10^6 points; in one SELECT it steps through every row: 0.2 s)
    n, lo, hi = db.execute(
        "SELECT (SELECT COUNT(*) FROM points), (SELECT MIN(seq) FROM points), (SELECT MAX(seq) FROM points)"
    ).fetchone()
    if n != planned:
        gone = f", {planned - n} deleted" if n < planned else f", {n - planned} added"
        return f"holds {n} point rows of the {planned} planned{gone}"
    if n and (lo, hi) != (0, n - 1):
        return f"has point rows out of grid order (seq {lo}…{hi}, expected 0…{n - 1})"
    if not thorough:
        return ""
    # ledgers written before a checksum was kept are checked by count (and JSON) only
    digests = RowDigests()
    cursor = db.execute("SELECT id, parameters FROM points ORDER BY seq")
    while rows := cursor.fetchmany(65536):
        digests.add(*zip(*rows))
    ids_only = {k: v for k, v in meta.items() if k != "points_checksum"}
    return digests.problem(ids_only) or parameters_problem(db) or digests.problem(meta)


def parameters_problem(db: sqlite3.Connection) -> str:
    """A point row whose parameters are not a JSON object ("" if none)."""
    bad = db.execute(
        "SELECT seq FROM points WHERE json_valid(parameters) = 0 OR json_type(parameters) != 'object' LIMIT 1"
    ).fetchone()
    return f"has a point row (seq {bad[0]}) whose parameters are not a JSON object" if bad is not None else ""


def points_checksum(db: sqlite3.Connection) -> str:
    """SHA-256 of every point's id and parameters (its JSON text) in grid order, one per line:
    a parameter edited in the ledger no longer matches (its log, and its id, keep the old one)."""
    digests = RowDigests()
    cursor = db.execute("SELECT id, parameters FROM points ORDER BY seq")
    while rows := cursor.fetchmany(65536):  # hashed a block at a time: the same bytes, 3× faster
        digests.add(*zip(*rows))
    return digests.points.hexdigest()


def ids_checksum(db: sqlite3.Connection) -> str:
    """SHA-256 of the point ids in grid order, one per line (as :meth:`Ledger.create` writes it)."""
    digest = hashlib.sha256()
    cursor = db.execute("SELECT id FROM points ORDER BY seq")
    while rows := cursor.fetchmany(65536):
        digest.update(_id_lines(pid for (pid,) in rows))
    return digest.hexdigest()


def _id_lines(ids: Iterable[str]) -> bytes:
    return "".join(f"{pid}\n" for pid in ids).encode()


class RowDigests:
    """The checksums of :func:`ids_checksum` and :func:`points_checksum` taken over rows that a
    reader reads anyway, a block at a time in grid order (the results table: one pass over a
    10^6-point ledger instead of three)."""

    def __init__(self) -> None:
        self.ids = hashlib.sha256()
        self.points = hashlib.sha256()

    def add(self, ids: Sequence[str], parameters: Sequence[str]) -> None:
        self.ids.update(_id_lines(ids))
        self.points.update("".join(f"{pid}\t{p}\n" for pid, p in zip(ids, parameters)).encode())

    def problem(self, meta: Mapping[str, str]) -> str:
        """What the rows added say is wrong against the checksums in ``meta`` ("" if nothing)."""
        if meta.get("ids_checksum") not in (None, self.ids.hexdigest()):
            return "has point rows that are not the planned ones (their ids changed)"
        if meta.get("points_checksum") not in (None, self.points.hexdigest()):
            return "has point rows whose parameters changed since they were planned (edited in the ledger?)"
        return ""


def verify(db: sqlite3.Connection, path: Path, *, thorough: bool = True, per_row: bool = True) -> None:
    """Raise :class:`LedgerDamaged` if the ledger open in ``db`` (the file ``path``) is not sound."""
    found = problem(db, thorough=thorough, per_row=per_row)
    if found:
        raise damaged(path, found)


def verify_digests(digests: RowDigests, meta: Mapping[str, str], path: Path) -> None:
    """Raise :class:`LedgerDamaged` if the rows added to ``digests`` disagree with ``meta``'s checksums."""
    found = digests.problem(meta)
    if found:
        raise damaged(path, found)


def check_plan(path: Path, ledger_ids: Sequence[str], planned_ids: Sequence[str]) -> None:
    """The ledger's point ids (grid order) must be the stored campaign's, re-planned."""
    if list(ledger_ids) != list(planned_ids):
        extra = len(set(ledger_ids) - set(planned_ids))
        lost = len(set(planned_ids) - set(ledger_ids))
        raise damaged(
            path,
            f"does not hold the stored campaign's points ({lost} planned point(s) missing, "
            f"{extra} foreign, or out of order)",
        )
