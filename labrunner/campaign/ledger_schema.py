"""The ledger's SQLite schema, and the additions an older ledger gains when opened for writing
(still schema version 1: only columns and indexes are ever added)."""

from __future__ import annotations

import sqlite3

from labrunner.run_identity import FINGERPRINT_COLUMNS

SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE points (
    seq INTEGER PRIMARY KEY,
    id TEXT NOT NULL UNIQUE,
    parameters TEXT NOT NULL,
    batch_key TEXT NOT NULL,
    state TEXT NOT NULL DEFAULT 'planned'
        CHECK (state IN ('planned', 'claimed', 'done', 'aborted', 'failed')),
    outcome TEXT CHECK (outcome IN ('completed', 'aborted', 'no-motion', 'failed')),
    outcome_json TEXT,
    rms_error REAL,
    input_energy REAL,
    max_abs_input REAL,
    metrics_json TEXT,
    log_path TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    host TEXT,
    pid INTEGER,
    claimed_at REAL,
    finished_at REAL,
    engine_s REAL,
    write_s REAL,
    publish_s REAL,
    log_size INTEGER,
    log_mtime_ns INTEGER,
    log_ctime_ns INTEGER,
    log_inode INTEGER
);
CREATE INDEX points_state ON points (state);
CREATE TABLE quarantine (
    n INTEGER PRIMARY KEY AUTOINCREMENT,
    point_id TEXT,
    original TEXT NOT NULL,
    moved_to TEXT NOT NULL,
    reason TEXT NOT NULL,
    bytes INTEGER,
    at REAL NOT NULL
);
CREATE TABLE sessions (
    n INTEGER PRIMARY KEY AUTOINCREMENT,
    command TEXT NOT NULL,
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    started_at REAL NOT NULL,
    last_at REAL NOT NULL,
    ended_at REAL,
    end_reason TEXT
);
"""


#: The partial index of the planned points (batch key, state, seq: every column its queries read), named by them.
PLANNED_INDEX = "points_planned"

#: Indexes that let ``status`` count outcomes and finished runs from small index b-trees instead of
#: scanning every row (0.6 s at 10^5 points without them), and the scheduler find the planned
#: points without reading their rows: created with a ledger, and added to an older one when it is
#: opened for writing.
INDEXES = (
    "CREATE INDEX IF NOT EXISTS points_outcome ON points (outcome, state)",
    "CREATE INDEX IF NOT EXISTS points_finished ON points (finished_at)",
    # the planned points by batch key, in grid order, from the index alone (a partial index: only
    # planned rows, so it shrinks to nothing as a campaign finishes): what the scheduler batches
    f"CREATE INDEX IF NOT EXISTS {PLANNED_INDEX} ON points (batch_key, state) WHERE state = 'planned'",
)


#: Columns added to the points table after its first version, with their types.
ADDED_COLUMNS = (("metrics_json", "TEXT"), *((c, "INTEGER") for c in FINGERPRINT_COLUMNS))


def migrate(db: sqlite3.Connection) -> None:
    """Add the columns and indexes later versions of this schema (still version 1: only additions) have."""
    columns = {r[1] for r in db.execute("PRAGMA table_info(points)")}
    for name, kind in ADDED_COLUMNS:
        if name not in columns:
            db.execute(f"ALTER TABLE points ADD COLUMN {name} {kind}")
    for index in INDEXES:
        db.execute(index)
