"""The campaign ledger: one SQLite database (WAL) per campaign directory, one row per grid point.

States: ``planned → claimed → done | aborted | failed`` ("done" covers the outcomes completed and
no-motion; the outcome itself is a column). One finished run = one published MCAP = one
transaction that moves its row from ``claimed`` to a terminal state; the update is conditional on
``state = 'claimed'``, so a run can never be committed twice. The database is created under a
temporary name and renamed into place, so a crash while planning leaves no half-written ledger.
The ``meta`` table keeps a copy of the campaign file and the checksum of the planned grid.
``metrics_json`` holds every metric of the run (:data:`labrunner.metrics.BASE_METRICS` and the
per-channel ones) as one JSON object, so that ``analyse`` tabulates without reading the logs; a
ledger made before that column existed gains it when opened for writing (:func:`~labrunner.campaign.ledger_schema.migrate`), and
readers treat a missing column as "no metrics here" (the analysis then reads the logs). Likewise
``log_size``, ``log_mtime_ns``, ``log_ctime_ns`` and ``log_inode``: the published log's
:func:`~labrunner.run_identity.fingerprint`, committed with its run, by which ``analyse`` knows a
log unchanged since without reading it (none recorded: it reads the log, as before).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import sqlite3
import time
from array import array
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from labrunner import jsontext, safefs
from labrunner.campaign import integrity
from labrunner.campaign.ledger_schema import INDEXES, PLANNED_INDEX, SCHEMA, migrate
from labrunner.errors import CampaignError, InvalidParameter
from labrunner.run_identity import FINGERPRINT_COLUMNS, Fingerprint

LEDGER_NAME = "ledger.sqlite"
STATES = ("planned", "claimed", "done", "aborted", "failed")
TERMINAL = ("done", "aborted", "failed")
STATE_OF_OUTCOME = {"completed": "done", "no-motion": "done", "aborted": "aborted", "failed": "failed"}
_FINGERPRINT_SET = ", ".join(f"{c} = ?" for c in FINGERPRINT_COLUMNS)
_SEQ_PAGE = 65536  # planned points' seq read at a time (:meth:`Ledger.planned_seqs`)


@dataclass(frozen=True)
class RunRecord:
    """What the parent commits for one finished run (built from a worker's summary)."""

    point_id: str
    outcome: str
    outcome_record: Mapping[str, Any]
    metrics: Mapping[str, float]
    log_path: str | None  # relative to the campaign directory; None: the run left no log
    host: str
    pid: int
    finished_at: float
    engine_s: float | None = None
    write_s: float | None = None
    publish_s: float | None = None
    log_fingerprint: Fingerprint | None = None  # the published log's, when it was written or proved


def ledger_path(directory: Path) -> Path:
    """``DIR/ledger.sqlite``, or a one-line refusal (exit 2) when DIR is not a campaign directory
    (exit 1 when the ledger or a side file SQLite opens is a link: SQLite follows links, and a
    planted one would make this another campaign's ledger, see :mod:`labrunner.safefs`)."""
    if not directory.is_dir():
        raise InvalidParameter(
            "DIR",
            f"{str(directory)!r} is not a directory" if directory.exists() else f"{str(directory)!r} does not exist",
        )
    path = directory / LEDGER_NAME
    safefs.check_sqlite(path)
    if not path.is_file():
        raise InvalidParameter(
            "DIR",
            f"{str(directory)!r} holds no campaign ledger ({LEDGER_NAME}); start one with "
            f"`labrunner run FILE`, or rebuild a lost one with `labrunner repair {directory}`",
        )
    return path


def _connect(path: Path) -> sqlite3.Connection:
    db = sqlite3.connect(path, isolation_level=None, timeout=30.0, check_same_thread=False)
    db.row_factory = sqlite3.Row
    db.execute("PRAGMA busy_timeout = 30000")
    return db


def connect_readonly(path: Path) -> sqlite3.Connection:
    """A read-only connection to the ledger at ``path``, also from a read-only copy.

    A ledger in WAL mode needs its ``-shm`` file even to be read; in a shared copy without
    ``-wal``/``-shm`` and without write access to the directory, SQLite cannot create it and
    answers "attempt to write a readonly database" — which is no damage. Such a copy is then
    opened ``immutable`` (no locks, no ``-shm``): correct because without a ``-wal`` file every
    committed transaction is in the database file, and nobody without write access changes it."""
    uri = path.resolve().as_uri()
    db = sqlite3.connect(f"{uri}?mode=ro", uri=True, isolation_level=None, timeout=30.0)
    try:
        db.execute("SELECT count(*) FROM sqlite_master").fetchone()
        return db
    except sqlite3.DatabaseError as exc:  # garbage, a truncated file: the integrity checks say how
        readonly = "readonly" in str(exc) or "unable to open" in str(exc)
        if not readonly or os.access(path.parent, os.W_OK):
            return db  # another problem: the integrity checks report it
        wal = path.with_name(path.name + "-wal")
        if wal.exists() and wal.stat().st_size:
            db.close()
            raise CampaignError(
                f"{path}: cannot be read without write access to {path.parent} (its {wal.name} holds "
                f"transactions not yet in the ledger file, and SQLite must create {path.name}-shm to read "
                f"them): read it where you can write, or copy the directory"
            ) from None
    db.close()
    return sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, isolation_level=None, timeout=30.0)


class Ledger:
    """An open ledger. Every method is one transaction; use :meth:`close` (or ``with``)."""

    def __init__(self, directory: Path, db: sqlite3.Connection) -> None:
        self.directory = directory
        self.db = db
        self.session: int | None = None
        #: Told, inside each transaction that moves points between states, how many left or entered
        #: each state (the session journal, :mod:`.journal`, keeps its counts so).
        self.on_moved: Callable[[Mapping[str, int]], None] | None = None

    # -- creation and opening ----------------------------------------------------------------
    @classmethod
    def create(
        cls,
        directory: Path,
        *,
        meta: Mapping[str, str],
        points: Iterable[tuple[int, str, Mapping[str, Any], str]],
    ) -> Ledger:
        """Write a new ledger atomically: (seq, id, parameters, batch key) rows, all ``planned``.

        The caller holds the directory's lock, so a temporary ledger found here is a leftover of a
        runner killed while it planned, and is removed."""
        final = directory / LEDGER_NAME
        safefs.check_sqlite(final)
        if final.exists():
            raise CampaignError(f"{final} already exists")
        for stale in directory.glob(f".{LEDGER_NAME}.*.tmp"):  # a creation killed before its rename
            stale.unlink()
        fd, tmp = safefs.temp_file(directory, f".{LEDGER_NAME}.", ".tmp")  # unpredictable, O_EXCL
        os.close(fd)
        safefs.check_sqlite(tmp)
        db = _connect(tmp)
        try:
            db.executescript(SCHEMA)
            for index in INDEXES:
                db.execute(index)
            db.execute("BEGIN")
            db.executemany(
                "INSERT INTO meta (key, value) VALUES (?, ?)",
                [("schema_version", integrity.SCHEMA_VERSION), *sorted(meta.items())],
            )
            ids = hashlib.sha256()

            def rows() -> Iterator[tuple[int, str, str, str]]:
                for s, i, p, k in points:
                    ids.update(f"{i}\n".encode())
                    yield s, i, json.dumps(dict(p), sort_keys=True), k

            db.executemany("INSERT INTO points (seq, id, parameters, batch_key) VALUES (?, ?, ?, ?)", rows())
            db.execute("INSERT INTO meta (key, value) VALUES ('ids_checksum', ?)", (ids.hexdigest(),))
            db.execute("INSERT INTO meta (key, value) VALUES ('points_checksum', ?)", (integrity.points_checksum(db),))
            if "points" not in meta:  # the planned count the integrity checks compare with
                db.execute("INSERT INTO meta (key, value) SELECT 'points', COUNT(*) FROM points")
            db.execute("COMMIT")
        except BaseException as exc:  # Ctrl-C or an error while planning: leave nothing half-written
            db.close()
            tmp.unlink(missing_ok=True)
            if isinstance(exc, sqlite3.Error):
                raise LedgerWriteError(f"{final}: cannot write the ledger: {exc}") from None
            raise
        db.close()
        fd = safefs.open_fd(tmp, os.O_RDWR)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        safefs.replace(tmp, final)
        fsync_dir(directory)
        return cls.open(directory, verify=False)  # just written

    @classmethod
    def open(cls, directory: Path, *, verify: bool = True) -> Ledger:
        """Open for writing (``run``, ``resume``); ``verify`` first checks it (:mod:`.integrity`)."""
        path = ledger_path(directory)
        db = _connect(path)
        try:
            if verify:
                integrity.verify(db, path)
            db.execute("PRAGMA journal_mode = WAL")
            db.execute("PRAGMA synchronous = NORMAL")
        except sqlite3.DatabaseError as exc:
            db.close()
            raise integrity.damaged(path, f"is not a readable ledger ({exc})") from None
        except BaseException:
            db.close()
            raise
        migrate(db)
        return cls(directory, db)

    @classmethod
    def open_readonly(
        cls, directory: Path, *, verify: bool = True, thorough: bool = True, per_row: bool = True
    ) -> Ledger:
        """Open for reading (``status``, ``analyse``): no journal-mode change, nothing written;
        ``thorough=False`` leaves out the checks that read every row, ``per_row=False`` those of the
        ids and parameters, for a reader that checks them over the rows it reads (:mod:`.integrity`)."""
        path = ledger_path(directory)
        db = connect_readonly(path)
        db.row_factory = sqlite3.Row
        try:
            if verify:
                integrity.verify(db, path, thorough=thorough, per_row=per_row)
        except BaseException:
            db.close()
            raise
        return cls(directory, db)

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Ledger:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reads ---------------------------------------------------------------------------------
    def meta(self) -> dict[str, str]:
        return {r["key"]: r["value"] for r in self.db.execute("SELECT key, value FROM meta")}

    def counts(self) -> dict[str, int]:
        return self.census()[0]

    def outcome_counts(self) -> dict[str, int]:
        rows = self.db.execute("SELECT outcome, COUNT(*) FROM points WHERE outcome IS NOT NULL GROUP BY outcome")
        return {r[0]: r[1] for r in rows}

    def by_outcome(self) -> dict[str, int]:
        """Points per outcome word (completed, no-motion, aborted, failed; claimed and planned for
        points without a finished run): what every command counts with."""
        return self.census()[1]

    def census(self) -> tuple[dict[str, int], dict[str, int]]:
        """(:meth:`counts`, :meth:`by_outcome`) from one pass over the ``points_outcome`` index, in
        its order: grouping by ``COALESCE(outcome, state)`` sorted every row first (~0.5 s rather
        than ~0.1 s at 10^6 points)."""
        states = {s: 0 for s in STATES}
        words: dict[str, int] = {}
        for outcome, state, n in self.db.execute("SELECT outcome, state, COUNT(*) FROM points GROUP BY outcome, state"):
            states[state] = states.get(state, 0) + n
            word = outcome if outcome is not None else state
            words[word] = words.get(word, 0) + n
        return states, words

    def rows(self, states: Sequence[str] | None = None, columns: str = "*") -> list[sqlite3.Row]:
        """Rows in grid order, optionally only those in ``states``; ``columns`` (SQL) narrows what
        is read (a million rows' outcome and metrics JSON are ~0.5 GB of Python strings)."""
        if states is None:
            return self.db.execute(f"SELECT {columns} FROM points ORDER BY seq").fetchall()
        marks = ",".join("?" * len(states))
        return self.db.execute(
            f"SELECT {columns} FROM points WHERE state IN ({marks}) ORDER BY seq", tuple(states)
        ).fetchall()

    def planned_seqs(self) -> list[tuple[str, array]]:
        """The planned points' ``seq`` in grid order, grouped by batch key (the groups in the order
        of their first point): read from the planned-points index alone, 8 bytes a point, so a
        scheduler batches 5×10^5 remaining points without reading their rows (their parameters:
        ~300 MB as Python objects). Rows are read a batch at a time (:meth:`rows_at`)."""
        cursor = self.db.cursor()
        cursor.row_factory = None  # plain tuples: a Row object per point costs twice the time
        where = f"FROM points INDEXED BY {PLANNED_INDEX} WHERE state = 'planned' AND batch_key"
        firsts, key = [], ""
        # each key and its first point by a seek in the index, not a pass over it (0.1 s at 5×10^5)
        while found := cursor.execute(f"SELECT batch_key {where} > ? ORDER BY batch_key LIMIT 1", (key,)).fetchone():
            key = found[0]
            firsts.append((cursor.execute(f"SELECT MIN(seq) {where} = ?", (key,)).fetchone()[0], key))
        return [(key, self._planned_seqs_of(cursor, where, key)) for _, key in sorted(firsts)]

    @staticmethod
    def _planned_seqs_of(cursor: sqlite3.Cursor, where: str, key: str) -> array:
        """One batch key's planned ``seq``, in grid order, :data:`_SEQ_PAGE` at a time after the
        last one read (keyset pagination over the index); each page one JSON array, which Python
        parses ~3× faster than it steps through as many rows (0.14 s rather than 0.37 s at 5×10^5)."""
        seqs, last = array("q"), -1
        page = f"SELECT json_group_array(seq), MAX(seq) FROM (SELECT seq {where} = ? AND seq > ? ORDER BY seq LIMIT ?)"
        while (found := cursor.execute(page, (key, last, _SEQ_PAGE)).fetchone())[1] is not None:
            seqs.extend(sorted(json.loads(found[0])))  # sorted: an aggregate's order is SQLite's to choose
            last = found[1]
        return seqs

    def rows_at(self, seqs: Sequence[int], columns: str = "*") -> list[sqlite3.Row]:
        """The rows at ``seqs`` (grid positions), in grid order."""
        return self.db.execute(
            f"SELECT {columns} FROM points WHERE seq IN (SELECT value FROM json_each(?)) ORDER BY seq",
            (json.dumps(list(seqs)),),
        ).fetchall()

    def iter_rows(self) -> Iterator[dict[str, Any]]:
        """Every row in grid order as a dict, read as it is consumed (a campaign of 10^6 points
        is never all in memory as Python objects); consume it while the ledger is open."""
        return (dict(r) for r in self.db.execute("SELECT * FROM points ORDER BY seq"))

    def ids(self) -> list[str]:
        """The points' ids in grid order (what a plan check needs, without the rest of the rows)."""
        return [r[0] for r in self.db.execute("SELECT id FROM points ORDER BY seq")]

    def quarantined(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM quarantine ORDER BY n").fetchall()

    def sessions(self) -> list[sqlite3.Row]:
        return self.db.execute("SELECT * FROM sessions ORDER BY n").fetchall()

    # -- writes --------------------------------------------------------------------------------
    def _txn(self):
        return _Transaction(self.db, self.directory / LEDGER_NAME)

    def set_meta(self, key: str, value: str | None) -> None:
        """Write (or, with None, remove) one ``meta`` entry."""
        with self._txn():
            self._put_meta(key, value)

    def _put_meta(self, key: str, value: str | None) -> None:
        if value is None:
            self.db.execute("DELETE FROM meta WHERE key = ?", (key,))
        else:
            self.db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    def set_fingerprints(self, fingerprints: Mapping[str, Fingerprint], meta: Mapping[str, str | None]) -> None:
        """Record the logs' new fingerprints (point id → fingerprint) and write (None: remove) the
        ``meta`` entries, in one transaction (``upgrade-logs``: rewritten logs and the end of
        their journal entry together)."""
        with self._txn():
            self.db.executemany(
                f"UPDATE points SET {_FINGERPRINT_SET} WHERE id = ?",
                [(*fp, point_id) for point_id, fp in fingerprints.items()],
            )
            for key, value in meta.items():
                self._put_meta(key, value)

    def start_session(self, command: str) -> int:
        now = time.time()
        with self._txn():
            cur = self.db.execute(
                "INSERT INTO sessions (command, host, pid, started_at, last_at) VALUES (?, ?, ?, ?, ?)",
                (command, socket.gethostname(), os.getpid(), now, now),
            )
        self.session = int(cur.lastrowid)
        return self.session

    def end_session(self, reason: str) -> None:
        if self.session is not None:
            now = time.time()
            with self._txn():
                self.db.execute(
                    "UPDATE sessions SET ended_at = ?, last_at = ?, end_reason = ? WHERE n = ?",
                    (now, now, reason, self.session),
                )

    def claim(self, ids: Sequence[str]) -> None:
        """planned → claimed (attempts + 1) for ``ids``, all or nothing."""
        host, pid, now = socket.gethostname(), os.getpid(), time.time()
        with self._txn():
            cur = self.db.executemany(
                "UPDATE points SET state = 'claimed', attempts = attempts + 1, host = ?, pid = ?, claimed_at = ?"
                " WHERE id = ? AND state = 'planned'",
                ((host, pid, now, i) for i in ids),
            )
            if cur.rowcount != len(ids):
                raise CampaignError(f"ledger: {len(ids) - cur.rowcount} of {len(ids)} points were not planned")
            self._moved({"planned": -len(ids), "claimed": len(ids)})

    def unclaim(self, ids: Sequence[str]) -> None:
        """claimed → planned for batches that never started or were stopped before they published
        anything (attempts − 1): nothing of theirs is recorded."""
        with self._txn():
            cur = self.db.executemany(
                "UPDATE points SET state = 'planned', attempts = attempts - 1, claimed_at = NULL"
                " WHERE id = ? AND state = 'claimed'",
                ((i,) for i in ids),
            )
            self._moved({"claimed": -cur.rowcount, "planned": cur.rowcount})

    def replan(self, ids: Sequence[str]) -> None:
        """Back to ``planned`` after a crash (claimed) or on request (failed); attempts are kept."""
        with self._txn():
            if self.on_moved is not None:
                self._moved(self._leaving(ids, "planned"))
            self.db.executemany(
                "UPDATE points SET state = 'planned', outcome = NULL, outcome_json = NULL, rms_error = NULL,"
                " input_energy = NULL, max_abs_input = NULL, metrics_json = NULL, log_path = NULL, finished_at = NULL,"
                f" {_FINGERPRINT_SET.replace('?', 'NULL')} WHERE id = ?",
                ((i,) for i in ids),
            )

    def commit(self, *records: RunRecord, from_states: Sequence[str] = ("claimed",)) -> None:
        """claimed → terminal for each run (a batch's runs: one transaction for all); refuses a
        second commit of any, and then commits none of them."""
        marks = ",".join("?" * len(from_states))
        with self._txn():
            if self.on_moved is not None:  # one journal update: the states left and those entered
                moved = self._leaving([r.point_id for r in records])
                moved.update(STATE_OF_OUTCOME[r.outcome] for r in records)
                self._moved(moved)
            for record in records:
                m = record.metrics
                cur = self.db.execute(
                    "UPDATE points SET state = ?, outcome = ?, outcome_json = ?, rms_error = ?, input_energy = ?,"
                    " max_abs_input = ?, metrics_json = ?, log_path = ?, host = ?, pid = ?, finished_at = ?,"
                    f" engine_s = ?, write_s = ?, publish_s = ?, {_FINGERPRINT_SET} WHERE id = ? AND state IN ({marks})",
                    (
                        STATE_OF_OUTCOME[record.outcome],
                        record.outcome,
                        jsontext.dumps(dict(record.outcome_record), sort_keys=True),
                        m.get("rms_error"),
                        m.get("input_energy"),
                        m.get("max_abs_input"),
                        jsontext.dumps(dict(m)) if m else None,
                        record.log_path,
                        record.host,
                        record.pid,
                        record.finished_at,
                        record.engine_s,
                        record.write_s,
                        record.publish_s,
                        *(record.log_fingerprint or (None,) * len(FINGERPRINT_COLUMNS)),
                        record.point_id,
                        *from_states,
                    ),
                )
                if cur.rowcount != 1:
                    raise CampaignError(
                        f"ledger: point {record.point_id} is not in state {'/'.join(from_states)}; not committed twice"
                    )
            if self.session is not None and records:
                self.db.execute("UPDATE sessions SET last_at = ? WHERE n = ?", (time.time(), self.session))

    def add_points(self, points: Iterable[tuple[str, Mapping[str, Any], str]]) -> int:
        """Append ``planned`` rows (id, parameters, batch key) after the last ``seq``, in one
        transaction: a guided campaign's next round. Returns the number of rows added."""
        with self._txn():
            last = self.db.execute("SELECT COALESCE(MAX(seq), -1) FROM points").fetchone()[0]
            rows = [(last + 1 + n, i, json.dumps(dict(p), sort_keys=True), k) for n, (i, p, k) in enumerate(points)]
            self.db.executemany("INSERT INTO points (seq, id, parameters, batch_key) VALUES (?, ?, ?, ?)", rows)
            self._moved({"planned": len(rows)})
            # the planned count and ids the integrity checks compare with grow with the rounds
            self.db.execute("UPDATE meta SET value = (SELECT COUNT(*) FROM points) WHERE key = 'points'")
            self.db.execute("UPDATE meta SET value = ? WHERE key = 'ids_checksum'", (integrity.ids_checksum(self.db),))
            self.db.execute(
                "UPDATE meta SET value = ? WHERE key = 'points_checksum'", (integrity.points_checksum(self.db),)
            )
        return len(rows)

    def _moved(self, delta: Mapping[str, int]) -> None:
        """Within a transaction that moved points between states: tell :attr:`on_moved`, if set."""
        if self.on_moved is not None:
            self.on_moved(delta)

    def _leaving(self, ids: Sequence[str], to: str | None = None) -> Counter:
        """How many of ``ids`` leave each state (read before the update moves them; to ``to``, if given)."""
        leaving: Counter = Counter()
        for (state,) in self.db.execute(
            "SELECT state FROM points WHERE id IN (SELECT value FROM json_each(?))", (json.dumps(list(ids)),)
        ):
            leaving[state] -= 1
            if to is not None:
                leaving[to] += 1
        return leaving

    def record_quarantine(self, point_id: str | None, original: str, moved_to: str, reason: str, size: int) -> None:
        with self._txn():
            self.db.execute(
                "INSERT INTO quarantine (point_id, original, moved_to, reason, bytes, at) VALUES (?, ?, ?, ?, ?, ?)",
                (point_id, original, moved_to, reason, size, time.time()),
            )


class LedgerWriteError(CampaignError):
    """SQLite could not write the ledger (a full disk, a file-size limit, an I/O error): the
    transaction was rolled back, so the ledger is as it was before it."""


class _Transaction:
    """``BEGIN IMMEDIATE`` … ``COMMIT`` (``ROLLBACK`` on error): one writer, no lost updates.
    An SQLite failure becomes a :class:`LedgerWriteError` naming the ledger file."""

    def __init__(self, db: sqlite3.Connection, path: Path) -> None:
        self.db, self.path = db, path

    def __enter__(self) -> None:
        try:
            self.db.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise self._error(exc) from None

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.db.execute("ROLLBACK" if exc_type else "COMMIT")
        except sqlite3.Error as failed:
            if exc_type is None:
                with contextlib.suppress(sqlite3.Error):
                    self.db.execute("ROLLBACK")
                exc = failed
        if isinstance(exc, sqlite3.Error):
            raise self._error(exc) from None

    def _error(self, exc: sqlite3.Error) -> LedgerWriteError:
        hint = " (disk full or file-size limit?)" if "disk" in str(exc) or "full" in str(exc) else ""
        return LedgerWriteError(f"{self.path}: cannot write the ledger: {exc}{hint}")


def fsync_dir(directory: Path) -> None:
    """Make a rename or file creation in ``directory`` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
