"""Guided campaigns through the ledger: rounds as ordinary rows, status, dry-run, and the same
decisions after a SIGKILL and ``resume`` (subprocess) as in an uninterrupted run."""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
from pathlib import Path

import pandas as pd
import pytest
from test_campaign_support import cli, comparable, ledger_rows, spawn, wait_for
from test_guided_support import write_campaign

from labrunner.campaign import guided_run, runner, spec
from labrunner.campaign.grid import point_id
from labrunner.campaign.ledger import Ledger

ROOT = Path(__file__).resolve().parents[1]
POLACK = {
    "procedure": "polack",
    "gamma_start": 1e4,
    "gamma_stop": 1.0,
    "kp_start": 0.1,
    "kp_stop": 1e3,
    "per_decade": 2,
}


def quiet(**kw) -> runner.Options:
    return runner.Options(workers=1, stream=io.StringIO(), **kw)


@pytest.fixture(scope="module")
def polack(tmp_path_factory) -> tuple[Path, Path]:
    """(the POLACK campaign file, one uninterrupted run of it): the reference that several tests
    read, run once per module instead of once per test (~2 s of CPU each). A test that writes into
    a run (analyse's report) takes a copy (:func:`_copy`) and leaves this one as it was."""
    root = tmp_path_factory.mktemp("polack")
    path = write_campaign(root, POLACK, name="pol")
    _, directory = runner.start(path, root / "ref", quiet())
    return path, Path(directory)


def _copy(directory: Path, to: Path) -> Path:
    """A copy of a finished run (logs with their modification times) that a test may write into."""
    return Path(shutil.copytree(directory, to))


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
    text = cli("status", directory, cwd=tmp_path).stdout
    assert f"{len(rows)} of at most 18 runs (feed-forward (k_p = 0): {len(ff)} runs" in text
    assert f"finished (tripped): chose step {g['chosen']['step']}" in text
    again, _ = runner.resume(directory, quiet())  # finished: nothing more to run
    assert again.committed == 0 and len(ledger_rows(Path(directory))) == len(rows)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_a_killed_guided_campaign_resumes_with_the_same_decisions(tmp_path, sig, polack):
    # SIGKILL: the runner dies mid-round; SIGINT (Ctrl-C): it finishes the running batch, exit 130
    path, ref = polack  # the uninterrupted run of the same campaign file (only read here)
    expected = comparable(ledger_rows(ref))
    proc = spawn("run", str(path), "--out", str(tmp_path / "cut"), "--workers", "1", cwd=tmp_path)
    try:
        assert wait_for(lambda: sum(r["state"] in ("done", "aborted") for r in ledger_rows(tmp_path / "cut")) >= 4, 90)
    finally:
        os.killpg(proc.pid, sig)
        code = proc.wait(30)
    assert code == (-signal.SIGKILL if sig == signal.SIGKILL else 130)
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
    assert runner.status(tmp_path / "cut")["guided"] == runner.status(ref)["guided"]


def test_resume_runs_a_round_that_was_written_but_not_run(tmp_path, polack):
    # a runner killed right after appending a round: its rows are planned; resume runs them, then goes on
    path, ref = polack  # the uninterrupted run of the same campaign file (only read here)
    campaign = spec.load(path)
    first, checksum = spec.plan(campaign)
    directory = tmp_path / "cut"
    directory.mkdir()
    meta = {
        "campaign": campaign.name,
        "campaign_file": campaign.source,
        "campaign_path": str(path.resolve()),
        "plan_checksum": checksum,
        "points": "1",
        "rig": campaign.rig,
        "guided": "polack",
    }
    Ledger.create(directory, meta=meta, points=((p.seq, p.id, p.parameters, p.batch_key) for p in first)).close()
    (directory / "runs").mkdir()
    runner.resume(directory, quiet())
    assert comparable(ledger_rows(directory)) == comparable(ledger_rows(ref))


def test_dry_run_says_guided_and_the_most_runs(tmp_path):
    result = cli(
        "run",
        str(ROOT / "campaigns" / "guided" / "guideline2-case1.toml"),
        "--dry-run",
        "--out",
        str(tmp_path / "g2"),
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith(
        "campaign guided-guideline2-case1: guided (guideline2) on rig 'dcmotor-sim', at most 97 runs"
    )
    for name, most in (("guideline2-bisect", 9), ("polack", 178), ("refine-gamma-kp", 4225)):
        _, text = runner.start(ROOT / "campaigns" / "guided" / f"{name}.toml", tmp_path / name, quiet(), dry=True)
        assert "guided (" in text.splitlines()[0] and f"at most {most} runs" in text.splitlines()[0]
    assert "first round: 81 point(s)" in text  # the refinement's coarse 9 × 9 grid
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    "name", ["guideline2-case1", "guideline2-bisect", "guideline2-case2", "guideline3", "polack", "refine-gamma-kp"]
)
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


def test_analysis_shows_the_walk_and_the_step_counts(tmp_path, polack):
    from labrunner.analysis.analyse import analyse

    directory = _copy(polack[1], tmp_path / "run")  # analyse writes its report into the run
    summary = analyse(directory, workers=1)
    rows = ledger_rows(Path(directory))
    walk = pd.read_csv(Path(directory) / "report" / "walk.csv")
    assert list(walk["id"]) == [r["id"] for r in rows] and walk["chosen"].sum() == 1
    assert list(walk["status"]) == [r["outcome"] for r in rows]
    assert summary["guided"]["runs"] == len(rows) and summary["guided"]["reason"] == "tripped"
    html = Path(summary["report"]).read_text()
    assert "Guided procedure" in html and "stage: feed-forward (k_p = 0)" in html
    assert (Path(directory) / "report" / "walk.png").stat().st_size > 10_000


def test_a_refined_boundary_shows_on_the_usual_map(tmp_path):
    from labrunner.analysis.analyse import analyse

    axes = {"controller.gamma": {"log10": [0.0, 4.0]}, "controller.k_p": {"log10": [-1.0, 3.0]}}
    path = write_campaign(tmp_path, {"procedure": "refine", "coarse": 3, "levels": 2, "axes": axes}, name="ref")
    _, directory = runner.start(path, tmp_path / "run", quiet())
    summary = analyse(directory, workers=1)
    detail = summary["guided"]["detail"]
    assert detail["resolution"] == [9, 9] and detail["boundary_cells"]
    assert summary["guided"]["runs"] == summary["runs"] < 81
    assert any(m.endswith("map_rms_error.png") for m in summary["maps"])  # the γ–k_p map of the refined points
    assert "boundary" in Path(summary["report"]).read_text()


def test_guideline2_against_polack_step_counts(tmp_path):
    from labrunner.campaign.guided_report import compare_guideline2_polack

    folder = tmp_path / "campaigns"
    folder.mkdir()
    g2 = {"procedure": "guideline2", "gamma_start": 1e6, "kp_start": 0.1, "gamma_stop": 1.0, "per_decade": 2}
    write_campaign(folder, g2, name="guideline2-case1")
    write_campaign(folder, {**POLACK, "gamma_start": 1e6}, name="polack")
    result = compare_guideline2_polack(tmp_path / "out", workers=1, campaigns=folder)
    g, p = result["guideline2"], result["polack"]
    assert p["runs"] == p["feed_forward"] + p["feedback"] == runner.status(tmp_path / "out" / "polack")["total"]
    assert g["runs"] == runner.status(tmp_path / "out" / "guideline2")["total"]
    rows = ledger_rows(tmp_path / "out" / "guideline2")  # a walk: its rows are its steps
    first = next(
        (
            n
            for n, row in enumerate(rows, 1)
            if row["outcome"] == "completed" and row["rms_error"] <= p["chosen"]["rms_error"]
        ),
        None,
    )
    assert g["runs_to_polack_rms"] == first  # None here: 2 steps a decade jump past Polack's RMS
    assert result["ratio_runs"] == pytest.approx(p["runs"] / g["runs"])
    assert result["thesis"] == {"guideline2": 54, "polack": 107, "polack_feed_forward": 66, "polack_feedback": 41}


def test_the_thesis_step_counts_on_the_motor_twin():
    # thesis Sec. 3.5.3: Guideline 2 reaches Polack's error after 54 steps, Polack et al. need
    # 66 + 41 = 107 — about twice as many. The shipped campaigns, outcomes simulated in process; a
    # miss simulates the whole ladder it belongs to in one lockstep batch (runs are independent).
    from labrunner.campaign import guided
    from labrunner.campaign.guided_report import step_counts
    from labrunner.campaign.guided_walks import GAMMA, KP

    def ladders(proc, point):
        if proc.name == "guideline2":
            return proc.line()
        if point[KP] == 0.0:
            return [{GAMMA: g, KP: 0.0} for g in proc.gammas()]
        return [{GAMMA: point[GAMMA], KP: k} for k in proc.gains()]

    walks = []
    for name in ("guideline2-case1", "polack"):
        campaign = spec.load(ROOT / "campaigns" / "guided" / f"{name}.toml")
        simulate, cache = guided_run.engine_oracle(campaign, batch=100), {}

        def oracle(points, proc=campaign.guided, simulate=simulate, cache=cache):
            key = lambda p: tuple(sorted(p.items()))  # noqa: E731
            for p in points:
                if key(p) not in cache:
                    family = ladders(proc, p)
                    cache.update(zip(map(key, family), simulate(family)))
            return [cache[key(p)] for p in points]

        walks.append(guided.drive(campaign.guided, campaign.name, oracle))
    result = step_counts(*walks)
    # runs, not the thesis's steps (changes of the setting: 48 here, item 3.5.3 of `labrunner reproduce`)
    assert result["guideline2"]["runs_to_polack_rms"] == 49
    assert result["polack"]["runs"] == pytest.approx(107, rel=0.1)
    assert result["polack"]["feed_forward"] == pytest.approx(66, rel=0.1)
    assert 1.7 <= result["ratio"] <= 2.3


def test_runs_to_polacks_rms_count_runs_not_the_points_a_walk_looks_at():
    """A point the walk looks at again is not a run: Guideline 2 looks at p0, p1, p0 again and p2, the first
    at Polack's RMS (0.5), after three runs; its position in the walk is 4."""
    from labrunner.campaign.guided import Advance, Observation, Result, WalkStep
    from labrunner.campaign.guided_report import step_counts

    def obs(i, rms):
        return Observation(f"p{i}", {"controller.gamma": 10.0**-i, "controller.k_p": 1.0}, "completed", rms, 1.0)

    p0, p1, p2 = obs(0, 2.0), obs(1, 1.0), obs(2, 0.4)
    g2 = Advance(
        (),
        "",
        Result(p2, "tripped"),
        (WalkStep("g2", p0, True), WalkStep("g2", p1, True), WalkStep("g2", p0, False), WalkStep("g2", p2, True)),
    )
    pol_choice = obs(9, 0.5)
    polack = Advance(
        (), "", Result(pol_choice, "tripped"), tuple(WalkStep("ff", obs(9 + k, 0.5), True) for k in range(6))
    )
    result = step_counts(g2, polack)
    assert result["guideline2"]["runs_to_polack_rms"] == 3 and result["ratio"] == 6 / 3


def test_status_and_analyse_give_the_same_chosen_point(tmp_path, polack):
    """Issue 36: `status` said the procedure chose one γ and `analyse` called another "best"."""
    directory = _copy(polack[1], tmp_path / "run")  # analyse writes its report into the run
    chosen = runner.status(directory)["guided"]["chosen"]
    out = cli("analyse", directory, "--workers", "1", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    gamma = chosen["params"]["controller.gamma"]
    line = f"chosen by the procedure (step {chosen['step']}): RMS(e) = {chosen['rms_error']:.4g} at "
    assert line + f"controller.gamma = {gamma:.4g}" in out.stdout
    assert not any(s.startswith("best:") for s in out.stdout.splitlines())  # no second answer
    html = (Path(directory) / "report" / "index.html").read_text()
    assert f"chosen: point {chosen['id']}" in html
