"""The session journal (labrunner.campaign.journal): after a crash it vouches for, ``resume``
settles the running points only and claims its first batch before any check that reads every row
or lists runs/; those checks run when the resumed session ends, so what they guard against — a
log deleted, a ledger edited — is still caught; a journal that does not hold (counts changed
behind its back, another boot) sends resume down the full path."""

from __future__ import annotations

import random
import sqlite3
from pathlib import Path

import pytest
from test_campaign_seal import _reference, _sealed, finished  # noqa: F401 - the fixture
from test_campaign_support import ledger_rows

from labrunner.campaign import integrity, journal, recovery, seal
from labrunner.campaign.ledger import Ledger, RunRecord
from labrunner.cli import main
from labrunner.errors import CampaignError


def _crashed(directory: Path) -> list[dict]:
    """The directory as a session killed mid-batch leaves it, its journal kept through its
    transactions: point 0 claimed with its log published but not committed, 1 claimed without a
    log, 2 claimed with only a temporary log, 3 planned; no seal."""
    rows = ledger_rows(directory)
    with Ledger.open(directory) as ledger:
        seal.clear(ledger)
        journal.begin(ledger, ledger.counts())
        ledger.replan([r["id"] for r in rows[:4]])
        ledger.claim([r["id"] for r in rows[:3]])
    for r in rows[1:4]:
        (directory / r["log_path"]).unlink()
    (directory / "runs" / f".tmp-{rows[2]['id']}-1-abcd.mcap").write_bytes(b"torn")
    return rows


@pytest.fixture
def crashed(request) -> tuple[Path, list[dict]]:
    """A finished campaign directory (test_campaign_seal's fixture) made :func:`_crashed`; its rows before."""
    directory = request.getfixturevalue("finished")
    return directory, _crashed(directory)


def _spy(monkeypatch) -> list[str]:
    """What resume does, in order: claims, the checks that read every row, runs/ listings."""
    events: list[str] = []
    problem, listing, claim = integrity.problem, seal.listing, Ledger.claim

    def checked(db, *, thorough=True, per_row=True):
        events.append("every row" if thorough and per_row else "structure")
        return problem(db, thorough=thorough, per_row=per_row)

    def listed(ledger):
        events.append("listing")
        return listing(ledger)

    def claimed(self, ids):
        events.append("claim")
        return claim(self, ids)

    monkeypatch.setattr(integrity, "problem", checked)
    monkeypatch.setattr(seal, "listing", listed)
    monkeypatch.setattr(Ledger, "claim", claimed)
    return events


def _meta(directory: Path) -> dict[str, str]:
    with Ledger.open_readonly(directory, verify=False) as ledger:
        return ledger.meta()


def test_after_a_crash_resume_settles_the_running_points_and_claims_before_reading_everything(
    crashed, monkeypatch, capsys
):
    directory, rows = crashed
    events = _spy(monkeypatch)
    monkeypatch.setattr(recovery, "recover", lambda ledger: pytest.fail("the journal vouches: no full recovery"))
    capsys.readouterr()
    assert main(["resume", str(directory), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    first = events.index("claim")
    assert "every row" not in events[:first] and "listing" not in events[:first]
    assert "every row" in events[first:] and "listing" in events[first:]  # the end-of-session check
    assert "1 published run(s) accepted" in err and "2 interrupted point(s) to rerun" in err
    after = {r["id"]: r for r in ledger_rows(directory)}
    assert after[rows[0]["id"]]["attempts"] == 2 and after[rows[1]["id"]]["attempts"] == 3  # kept; run again
    assert _sealed(directory) and _reference(directory) and journal.META_KEY not in _meta(directory)
    with Ledger.open_readonly(directory) as ledger:  # the torn file: quarantined when the session ended
        assert [q["original"] for q in ledger.quarantined()] == [f"runs/.tmp-{rows[2]['id']}-1-abcd.mcap"]


def _edit_a_state(d: Path, rows: list[dict]) -> None:
    with sqlite3.connect(d / "ledger.sqlite") as db:
        db.execute("UPDATE points SET state = 'failed', outcome = 'failed' WHERE id = ?", (rows[6]["id"],))


def _another_boot(d: Path, rows: list[dict], monkeypatch, tmp_path: Path) -> None:
    boot = tmp_path / "boot_id"
    boot.write_text("another boot\n")
    monkeypatch.setattr(journal, "BOOT_ID", boot)
    # what a power cut can leave: a planned point (its claim lost) whose log the worker had fsynced
    with Ledger.open(d) as ledger:
        ledger.on_moved = None
        ledger.unclaim([rows[0]["id"]])


@pytest.mark.parametrize("change", ["state", "boot"])
def test_a_journal_that_does_not_hold_sends_resume_down_the_full_path(crashed, change, monkeypatch, tmp_path, capsys):
    directory, rows = crashed
    if change == "state":
        _edit_a_state(directory, rows)
    else:
        _another_boot(directory, rows, monkeypatch, tmp_path)
    with Ledger.open_readonly(directory, verify=False) as ledger:
        assert not journal.holds(ledger, ledger.counts())
    full = []
    recover = recovery.recover
    monkeypatch.setattr(recovery, "recover", lambda ledger: full.append(1) or recover(ledger))
    capsys.readouterr()
    assert main(["resume", str(directory), "--workers", "1"]) == 0
    assert full == [1]
    if change == "boot":  # the planned point's published log is found and accepted
        assert "1 published run(s) accepted" in capsys.readouterr().err
        assert {r["id"]: r for r in ledger_rows(directory)}[rows[0]["id"]]["attempts"] == 1
    assert _sealed(directory) and _reference(directory)


def test_a_log_deleted_after_the_crash_is_caught_when_the_resumed_session_ends(crashed, capsys):
    directory, rows = crashed
    (directory / rows[5]["log_path"]).unlink()  # by hand: the journal cannot know
    capsys.readouterr()
    assert main(["resume", str(directory), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "end-of-session check did not pass" in err and not _sealed(directory)
    assert journal.META_KEY not in _meta(directory)  # the next resume checks everything
    assert main(["resume", str(directory), "--workers", "1"]) == 0
    assert "1 missing log(s) to rerun" in capsys.readouterr().err
    assert {r["id"]: r for r in ledger_rows(directory)}[rows[5]["id"]]["attempts"] == 2
    assert _sealed(directory) and _reference(directory)


@pytest.mark.parametrize(
    "edit, refusal",
    [
        ("UPDATE points SET id = 'foreign' WHERE id = ?", "their ids changed"),
        ("UPDATE points SET parameters = '[1, 2]' WHERE id = ?", "parameters are not a JSON object"),
    ],
)
def test_a_ledger_edited_after_the_crash_is_refused_once_the_resumed_session_ends(crashed, edit, refusal, capsys):
    directory, rows = crashed
    with sqlite3.connect(directory / "ledger.sqlite") as db:  # the states' counts unchanged
        db.execute(edit, (rows[7]["id"],))
    capsys.readouterr()
    main(["resume", str(directory), "--workers", "1"])
    assert "end-of-session check did not pass" in capsys.readouterr().err and not _sealed(directory)
    assert main(["resume", str(directory), "--workers", "1"]) == 2
    assert refusal in capsys.readouterr().err


def _record(pid: str, outcome: str) -> RunRecord:
    return RunRecord(pid, outcome, {"status": outcome}, {}, None, "h", 1, 0.0)


def test_the_journal_counts_follow_every_transaction_and_a_rolled_back_one_not(tmp_path):
    rng = random.Random(4)
    ids = [f"p{i}" for i in range(60)]
    points = [(i, pid, {"k": i}, '["rig", 200.0, 1.0, [], 0]') for i, pid in enumerate(ids)]
    with Ledger.create(tmp_path, meta={"campaign": "j", "points": "60"}, points=points) as ledger:
        journal.begin(ledger, ledger.counts())
        for step in range(200):
            states = {r["id"]: r["state"] for r in ledger.rows(None, "id, state")}
            by = {s: [i for i, t in states.items() if t == s] for s in set(states.values())}
            op = rng.choice(["claim", "unclaim", "commit", "replan", "add", "refused"])
            some = lambda state: rng.sample(by.get(state, []), min(len(by.get(state, [])), rng.randint(1, 5)))  # noqa: E731
            if op == "claim" and by.get("planned"):
                ledger.claim(some("planned"))
            elif op == "unclaim":
                ledger.unclaim(some("claimed") + some("planned"))  # planned ones are left as they are
            elif op == "commit" and by.get("claimed"):
                ledger.commit(*(_record(p, rng.choice(["completed", "aborted", "failed"])) for p in some("claimed")))
            elif op == "replan":
                ledger.replan(some("failed") + some("done") + some("claimed"))
            elif op == "add":
                ledger.add_points([(f"n{step}", {"k": step}, points[0][3])])
            elif op == "refused" and by.get("planned"):  # one point not claimed: the whole commit rolls back
                with pytest.raises(CampaignError):
                    ledger.commit(_record(by["planned"][0], "completed"))
            assert journal.holds(ledger, ledger.counts()), (step, op)
        with sqlite3.connect(tmp_path / "ledger.sqlite") as other:  # behind its back
            other.execute("UPDATE points SET state = 'planned' WHERE state != 'planned'")
        assert not journal.holds(ledger, ledger.counts())
