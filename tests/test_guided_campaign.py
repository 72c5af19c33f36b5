"""Guided campaigns through the ledger: rounds as ordinary rows, status, dry-run, and the same
decisions after a SIGKILL and ``resume`` (subprocess) as in an uninterrupted run."""

from __future__ import annotations

import io
import json
import os
import signal
from pathlib import Path

import pytest

from labrunner.campaign import guided_run, runner, spec
from labrunner.campaign.grid import point_id
from labrunner.campaign.ledger import Ledger

from test_campaign_support import cli, comparable, ledger_rows, spawn, wait_for
from test_guided_support import write_campaign

ROOT = Path(__file__).resolve().parents[1]
POLACK = {"procedure": "polack", "gamma_start": 1e4, "gamma_stop": 1.0, "kp_start": 0.1, "kp_stop": 1e3, "per_decade": 2}


def quiet(**kw) -> runner.Options:
    return runner.Options(workers=1, stream=io.StringIO(), **kw)


def test_rows_are_the_walk_and_status_reports_the_decision(tmp_path):
    path = write_campaign(tmp_path, POLACK, name="pol")
    out, directory = runner.start(path, tmp_path / "run", quiet())
    rows = ledger_rows(Path(directory))
    state = guided_run.directory_state(directory)[1]
    # every row is a point the plan asked for, in the order it asked, each run once
    assert [r["id"] for r in rows] == [s.observation.id for s in state.walk if s.new]
    assert all(r["state"] in ("done", "aborted") and r["attempts"] == 1 for r in rows)
    ff = [json.loads(r["parameters"]) for r in rows if json.loads(r["parameters"])["controller.k_p"] == 0.0]
    assert rows[len(ff) - 1]["outcome"] == "aborted"  # the feed-forward stage ends with its trip
    status = runner.status(directory)
    g = status["guided"]
    assert g["finished"] and g["runs"] == len(rows) == status["total"] and g["max_runs"] == 9 + 9
    assert [v["runs"] for v in g["stages"].values()] == [len(ff), len(rows) - len(ff)]
    assert g["chosen"]["id"] in {r["id"] for r in rows if r["outcome"] == "completed"}
    again, _ = runner.resume(directory, quiet())  # finished: nothing more to run
    assert again.committed == 0 and len(ledger_rows(Path(directory))) == len(rows)


def test_a_killed_guided_campaign_resumes_with_the_same_decisions(tmp_path):
    path = write_campaign(tmp_path, POLACK, name="pol")
    reference, _ = runner.start(path, tmp_path / "ref", quiet())
    expected = comparable(ledger_rows(tmp_path / "ref"))
    proc = spawn("run", str(path), "--out", str(tmp_path / "cut"), "--workers", "1", cwd=tmp_path)
    try:
        assert wait_for(lambda: sum(r["state"] in ("done", "aborted") for r in ledger_rows(tmp_path / "cut")) >= 4, 90)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    cut = ledger_rows(tmp_path / "cut")
    assert 4 <= len(cut) < len(expected)
    # the decision state comes from the ledger alone: the replay asks for the reference's next point
    campaign = spec.load(path)
    terminal = [r for r in cut if r["state"] in ("done", "aborted")]
    state = guided_run.replay(campaign, terminal)
    assert point_id(campaign.name, state.next[0]) == expected[len(terminal)][0]
    done = cli("resume", str(tmp_path / "cut"), "--workers", "1", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert comparable(ledger_rows(tmp_path / "cut")) == expected
    assert runner.status(tmp_path / "cut")["guided"] == runner.status(tmp_path / "ref")["guided"]


def test_resume_runs_a_round_that_was_written_but_not_run(tmp_path):
    # a runner killed right after appending a round: its rows are planned; resume runs them, then goes on
    path = write_campaign(tmp_path, POLACK, name="pol")
    runner.start(path, tmp_path / "ref", quiet())
    campaign = spec.load(path)
    first, checksum = spec.plan(campaign)
    directory = tmp_path / "cut"
    directory.mkdir()
    meta = {"campaign": campaign.name, "campaign_file": campaign.source, "campaign_path": str(path.resolve()),
            "plan_checksum": checksum, "points": "1", "rig": campaign.rig, "guided": "polack"}
    Ledger.create(directory, meta=meta, points=((p.seq, p.id, p.parameters, p.batch_key) for p in first)).close()
    (directory / "runs").mkdir()
    runner.resume(directory, quiet())
    assert comparable(ledger_rows(directory)) == comparable(ledger_rows(tmp_path / "ref"))


def test_dry_run_says_guided_and_the_most_runs(tmp_path):
    result = cli("run", str(ROOT / "campaigns" / "guided" / "guideline2-case1.toml"), "--dry-run", "--out",
                 str(tmp_path / "g2"), cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("campaign guided-guideline2-case1: guided (guideline2) on rig 'dcmotor-sim', at most 97 runs")
    for name, most in (("guideline2-bisect", 9), ("polack", 178), ("refine-gamma-kp", 4225)):
        _, text = runner.start(ROOT / "campaigns" / "guided" / f"{name}.toml", tmp_path / name, quiet(), dry=True)
        assert "guided (" in text.splitlines()[0] and f"at most {most} runs" in text.splitlines()[0]
    assert "first round: 81 point(s)" in text  # the refinement's coarse 9 × 9 grid
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["guideline2-case1", "guideline2-bisect", "guideline2-case2", "guideline3",
                                  "polack", "refine-gamma-kp"])
def test_shipped_guided_campaigns_validate(name):
    campaign = spec.load(ROOT / "campaigns" / "guided" / f"{name}.toml")
    first, checksum = spec.plan(campaign)
    assert first and len(checksum) == 64
    text = (ROOT / "campaigns" / "guided" / f"{name}.toml").read_text()
    assert text.startswith("# Thesis Sec. 3.5")  # each file is headed by the section it implements


def test_a_bad_guided_file_is_refused_before_anything_exists(tmp_path):
    path = write_campaign(tmp_path, {"procedure": "guideline2", "gamma_start": 1e3, "gamma_stop": 1e4})
    result = cli("run", str(path), "--out", str(tmp_path / "out"), cwd=tmp_path)
    assert result.returncode == 2
    assert "guided.gamma_stop: must be < the start 1000" in result.stderr
    assert not (tmp_path / "out").exists()
