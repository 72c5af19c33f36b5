"""The scheduler batches the planned points from the ledger's planned-points index, a batch's rows
read as it is submitted: the same batches in the same order as cutting every planned row read
at once (a plain reference here), retried and failed points mixed in, and the first batch is
claimed after reading O(batch) rows."""

from __future__ import annotations

import json
import math
import random
from collections import Counter
from concurrent.futures import Future

import pytest
from test_campaign_supervision import Scripted, _ledger

from labrunner.campaign import ledger as ledger_mod, scheduler as scheduler_mod
from labrunner.campaign.ledger import Ledger, RunRecord
from labrunner.campaign.scheduler import Scheduler, StopSignals, planned_batches
from labrunner.campaign.worker import BatchResult, BatchTask, RunTask

KEYS = [json.dumps(["rig", 200.0, d, [], 0]) for d in (2.0, 0.5, 30.0)]


def _reference(ledger: Ledger, slots: int, requested: int | None) -> list[tuple[str, list[str]]]:
    """Every planned row read at once, grouped by batch key in the order of each key's first
    point, each group cut as the scheduler's docstring says (strided, or in grid order)."""
    groups: dict[str, list[str]] = {}
    for row in ledger.db.execute("SELECT id, batch_key FROM points WHERE state = 'planned' ORDER BY seq"):
        groups.setdefault(row["batch_key"], []).append(row["id"])
    out = []
    for key, ids in groups.items():
        _, fs, duration, *_ = json.loads(key)
        size = scheduler_mod.batch_size(len(ids), slots, round(fs * duration), requested)
        count = math.ceil(len(ids) / size)
        if requested is None:
            out += [(key, [ids[k] for k in range(j, len(ids), count)]) for j in range(count)]
        else:
            out += [(key, ids[lo : lo + size]) for lo in range(0, len(ids), size)]
    return out


def _record(pid: str, outcome: str) -> RunRecord:
    return RunRecord(pid, outcome, {"status": outcome}, {}, None, "h", 1, 0.0)


def _mixed_ledger(tmp_path, n: int, seed: int) -> Ledger:
    """``n`` points over three batch keys (runs of keys, not sorted by key), then some runs
    finished, some failed and replanned (retries: attempts kept), some left claimed."""
    rng = random.Random(seed)
    keys = [KEYS[rng.randrange(3)] if rng.random() < 0.2 else KEYS[0] for _ in range(n)]
    points = [(s, f"p{s:05d}", {"k_p": s}, keys[s]) for s in range(n)]
    directory = tmp_path / f"d{seed}"
    directory.mkdir()
    ledger = Ledger.create(directory, meta={"campaign": "m", "points": str(n)}, points=points)
    ids = [p[1] for p in points]
    claimed = rng.sample(ids, n // 2)
    ledger.claim(claimed)
    finished = claimed[: n // 3]
    ledger.commit(*(_record(pid, rng.choice(["completed", "aborted", "failed"])) for pid in finished))
    retried = [pid for pid in claimed[n // 3 : n // 3 + n // 10]]
    ledger.replan(retried)  # after a crash: back to planned, attempts kept
    failed = [r["id"] for r in ledger.rows(("failed",), "id")][: n // 20]
    ledger.replan(failed)  # --retry-failed
    return ledger


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("slots, requested", [(1, None), (2, None), (3, None), (2, 7), (1, 1)])
def test_index_batches_are_the_read_all_batches_in_order(tmp_path, seed, slots, requested, monkeypatch):
    n = [1, 2, 37, 500, 3000, 9000][seed]
    monkeypatch.setattr(ledger_mod, "_SEQ_PAGE", [1, 2, 5, 64, 1000, 65536][seed])  # pages of the index read
    with _mixed_ledger(tmp_path, n, seed) as ledger:
        expected = _reference(ledger, slots, requested)
        found = planned_batches(ledger, slots, requested)
        as_ids = [(key, [r["id"] for r in ledger.rows_at(seqs, "id")]) for key, seqs in found]
        assert as_ids == expected
        # and the cutting the dry run still applies to rows it holds agrees
        rows = ledger.rows(("planned",), "id, batch_key")
        assert [(k, [r["id"] for r in b]) for k, b in scheduler_mod.make_batches(rows, slots, requested)] == expected


def test_the_scheduler_submits_the_reference_batches_with_their_attempts(project):
    campaign, ledger = _ledger(project, n=40)
    ids = [r["id"] for r in ledger.rows(None, "id")]
    ledger.claim(ids[:10])
    ledger.replan(ids[:4])  # retried: attempts 1 → the next run is attempt 2
    ledger.commit(*(_record(pid, "completed") for pid in ids[4:10]))
    expected = _reference(ledger, 2, 3)
    attempts = {r["id"]: r["attempts"] for r in ledger.rows(None, "id, attempts")}
    tasks = []

    def batch_fn(task):
        tasks.append(task)
        return BatchResult()  # nothing run: its points stay claimed

    class Now(Scripted):
        def submit(self, fn, /, *args, **kwargs) -> Future:
            future: Future = Future()
            future.set_result(fn(*args))
            return future

    sched = Scheduler(campaign, ledger, executor=Now(), slots=2, batch_size=3, batch_fn=batch_fn, signals=StopSignals())
    sched.run()
    assert [[r.point_id for r in t.runs] for t in tasks] == [ids_ for _, ids_ in expected]
    assert all(r.attempt == attempts[r.point_id] + 1 for t in tasks for r in t.runs)
    assert {r.point_id: r.attempt for r in tasks[0].runs} == {pid: 2 for pid in ids[:3]}
    ledger.close()


class _Counted:
    """A cursor that counts the rows it hands out, by statement."""

    def __init__(self, cursor, log: Counter) -> None:
        object.__setattr__(self, "_c", cursor)
        object.__setattr__(self, "_log", log)
        object.__setattr__(self, "_sql", "")

    def execute(self, sql, params=()):
        self._c.execute(sql, params)
        object.__setattr__(self, "_sql", sql)
        return self

    def executemany(self, sql, params):
        self._c.executemany(sql, params)
        return self

    def __iter__(self):
        for row in self._c:
            self._log[self._sql] += 1
            yield row

    def fetchall(self):
        rows = self._c.fetchall()
        self._log[self._sql] += len(rows)
        return rows

    def fetchone(self):
        row = self._c.fetchone()
        self._log[self._sql] += row is not None
        return row

    def __getattr__(self, name):
        return getattr(self._c, name)

    def __setattr__(self, name, value):
        setattr(self._c, name, value)


class _CountingDb:
    """An SQLite connection whose cursors count the rows they hand out."""

    def __init__(self, db) -> None:
        self._db, self.log = db, Counter()

    def cursor(self):
        return _Counted(self._db.cursor(), self.log)

    def execute(self, sql, params=()):
        return self.cursor().execute(sql, params)

    def executemany(self, sql, params):
        return self.cursor().executemany(sql, params)

    def __getattr__(self, name):
        return getattr(self._db, name)


class _Claimed(Exception):
    pass


def test_the_first_batch_is_claimed_after_reading_a_batch_of_rows(tmp_path):
    n, size = 20_000, 50
    with _mixed_ledger(tmp_path, n, 7) as ledger:
        planned = ledger.counts()["planned"]
        counting = _CountingDb(ledger.db)
        ledger.db = counting

        def claim(ids):
            raise _Claimed(len(ids))

        ledger.claim = claim
        sched = Scheduler(None, ledger, executor=Scripted(), slots=2, batch_size=size, signals=StopSignals())
        runs = lambda rows: tuple(RunTask(r["id"], r["attempts"] + 1, {}, {}, 0) for r in rows)  # noqa: E731
        sched._task = lambda key, rows: BatchTask("d", "m", "", "rig", (), {}, 200.0, 2.0, runs(rows))
        with pytest.raises(_Claimed):
            sched.run()
        index_scans = {sql: k for sql, k in counting.log.items() if "INDEXED BY points_planned" in sql}
        others = sum(k for sql, k in counting.log.items() if sql not in index_scans)
        assert index_scans and planned > 10 * size  # every planned point's seq, from the index ...
        for sql in index_scans:  # ... which alone answers (no row of the table is read)
            plan = " ".join(r[-1] for r in ledger.db._db.execute(f"EXPLAIN QUERY PLAN {sql}", ("x",) * sql.count("?")))
            assert "COVERING INDEX points_planned" in plan and "TEMP B-TREE" not in plan
        assert others <= size + 10  # rows read: the first batch's, and a few counts
