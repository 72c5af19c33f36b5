"""``labrunner run / resume / status`` end to end on the simulated DC motor (real engine, real logs)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tomllib

import pytest
from test_campaign_support import (
    MOTOR_RIG,
    campaign_text,
    cli,
    comparable,
    ledger_rows,
    spawn,
    wait_for,
    write,
)

from labrunner.cli import main
from labrunner.logs import read_run
from labrunner.rigs.registry import register_rig
from labrunner.rigs.sim.dcmotor import DCMotorTwin

TERMINAL = ("done", "aborted", "failed")


def test_run_then_status_and_logs(project, capsys):
    path = write(project / "campaigns" / "tiny.toml", campaign_text())
    assert main(["run", str(path), "--workers", "2"]) == 0
    directory = project / "data" / "tiny"
    rows = ledger_rows(directory)
    assert len(rows) == 9 and {r["state"] for r in rows} == {"done", "aborted"}
    assert {r["outcome"] for r in rows} <= {"completed", "no-motion", "aborted"}
    assert all((r["state"] == "done") == (r["outcome"] in ("completed", "no-motion")) for r in rows)
    assert (directory / "campaign.toml").read_text() == path.read_text()
    row = rows[4]
    log = read_run(directory / row["log_path"])
    assert not log.torn and log.outcome["status"] == row["outcome"]
    assert log.metadata["run"]["point_id"] == row["id"] and log.metadata["run"]["attempt"] == 1
    assert log.metadata["parameters"] == json.loads(row["parameters"])
    assert log.metadata["metrics"]["rms_error"] == pytest.approx(row["rms_error"], rel=1e-12)
    assert log.attachments["campaign.toml"].decode() == path.read_text()
    rig_file = tomllib.loads(MOTOR_RIG)  # the rig as it ran: the file's sections, defaults filled in
    rig = log.metadata["rig"]
    assert rig["rig"]["kind"] == "dcmotor" and rig["rig"]["description"] == rig_file["rig"]["description"]
    assert rig["parameters"] == {**{k: p.default for k, p in DCMotorTwin.PARAMETERS.items()}, **rig_file["parameters"]}
    assert rig["noise"] == {"input_v": DCMotorTwin.NOISE["input_v"].default} and rig["safety"] == rig_file["safety"]
    capsys.readouterr()
    assert main(["status", str(directory), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    o = st["outcomes"]
    assert st["campaign"] == "tiny" and st["total"] == 9 and o["planned"] == o["claimed"] == 0
    assert (
        o["completed"] + o["no-motion"] + o["aborted"] + o["failed"] == 9
        and st["elapsed_s"] > 0
        and st["running"] is None
    )
    assert main(["status", str(directory)]) == 0
    assert "9 points" in capsys.readouterr().out


def test_bad_executor_address_is_refused_before_anything_exists(project, capsys):
    path = write(project / "tiny.toml", campaign_text())
    assert main(["run", str(path), "--executor", "localhost:8786"]) == 2
    assert "--executor: must be a Dask scheduler address" in capsys.readouterr().err
    assert not (project / "data").exists()


def test_existing_campaign_directory_is_refused_with_a_resume_hint(project, capsys):
    path = write(project / "tiny.toml", campaign_text(grid='"controller.k_p" = { values = [10.0] }'))
    assert main(["run", str(path)]) == 0
    capsys.readouterr()
    assert main(["run", str(path)]) == 1
    assert "labrunner resume data/tiny" in capsys.readouterr().err
    write(project / "elsewhere" / "notes.txt", "mine")
    assert main(["run", str(path), "--out", "elsewhere"]) == 1
    assert "not an empty campaign directory" in capsys.readouterr().err


def test_resume_runs_the_campaigns_own_copy_and_says_the_file_was_edited(project, capsys):
    grid = '"controller.k_p" = { values = [10.0, 20.0, 40.0] }'
    path = write(project / "tiny.toml", campaign_text(grid=grid))
    assert main(["run", str(path), "--workers", "1"]) == 0
    (project / "data" / "tiny" / ledger_rows(project / "data" / "tiny")[2]["log_path"]).unlink()  # runs again
    path.write_text(path.read_text().replace("values = [10.0, 20.0, 40.0]", "values = [10.0, 30.0]"))  # a variant
    capsys.readouterr()
    assert main(["resume", "data/tiny", "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert f"note: {path} changed since this campaign began; resuming from its own copy, data/tiny/campaign.toml" in err
    rows = ledger_rows(project / "data" / "tiny")
    assert [json.loads(r["parameters"])["controller.k_p"] for r in rows] == [10.0, 20.0, 40.0]  # the stored grid
    assert {r["state"] for r in rows} <= set(TERMINAL) and [r["attempts"] for r in rows] == [1, 1, 2]
    assert read_run(project / "data" / "tiny" / rows[2]["log_path"]).metadata["config"]["controller"]["k_p"] == 40.0
    path.write_text((project / "data" / "tiny" / "campaign.toml").read_text())
    capsys.readouterr()
    assert main(["resume", "data/tiny"]) == 0
    assert "note:" not in capsys.readouterr().err  # the same text again: nothing to say


def test_resume_trusts_the_stored_plan_only_while_its_inputs_are_unchanged(project, capsys, monkeypatch):
    """Resume re-plans (0.2–1 ms a point: minutes at 10^6) only when the plan's inputs changed;
    a re-plan that differs is refused."""
    from labrunner.campaign import plan_inputs, spec

    write(project / "rigs" / "bench.toml", MOTOR_RIG)
    path = write(project / "tiny.toml", campaign_text(rig="rigs/bench.toml"))
    assert main(["run", str(path)]) == 0
    planned = []
    real_plan = spec.plan
    monkeypatch.setattr(spec, "plan", lambda c: planned.append(c) or real_plan(c))
    assert main(["resume", "data/tiny"]) == 0 and planned == []  # inputs unchanged: not re-planned
    text = path.read_text()
    path.write_text("# a comment\n" + text)
    assert main(["resume", "data/tiny"]) == 0 and planned == []  # a comment is not an input
    path.write_text(text)
    with monkeypatch.context() as m:
        m.setattr(plan_inputs, "code_digest", lambda files: "another labrunner")
        assert main(["resume", "data/tiny"]) == 0 and len(planned) == 1  # re-planned: the same checksum
        assert main(["resume", "data/tiny"]) == 0 and len(planned) == 1  # ... and its inputs stored: once
    assert main(["resume", "data/tiny"]) == 0 and len(planned) == 2  # the code changed back
    write(project / "rigs" / "bench.toml", MOTOR_RIG.replace("a = 39.44", "a = 40.0"))
    assert main(["resume", "data/tiny"]) == 0 and len(planned) == 3  # the rig file is an input
    monkeypatch.setattr(spec, "plan", lambda c: (real_plan(c)[0], "another plan"))
    write(project / "rigs" / "bench.toml", MOTOR_RIG.replace("a = 39.44", "a = 41.0"))
    capsys.readouterr()
    assert main(["resume", "data/tiny"]) == 1  # a re-plan that differs is refused, as before
    assert "no longer plans the same runs" in capsys.readouterr().err


def test_status_searches_outcomes_for_law_checks_only_for_a_real_rig(project):
    """A twin campaign's ledger says its rig is simulated, so status skips the search of every
    outcome for device-loop law checks (~3 s at 10^6 rows); a ledger without the key is searched."""
    import sqlite3

    from labrunner.campaign.runner import status

    path = write(project / "tiny.toml", campaign_text(grid='"controller.k_p" = { values = [10.0, 20.0] }'))
    assert main(["run", str(path)]) == 0
    db = sqlite3.connect(project / "data" / "tiny" / "ledger.sqlite")
    assert db.execute("SELECT value FROM meta WHERE key = 'real_rig'").fetchone() == ("0",)
    flagged = json.dumps({"status": "completed", "diagnostics": {"law_check": {"flag": "diverged"}}})
    with db:
        db.execute("UPDATE points SET outcome_json = ? WHERE seq = 0", (flagged,))
    assert "law_check" not in status(project / "data" / "tiny")
    with db:
        db.execute("DELETE FROM meta WHERE key = 'real_rig'")
    assert status(project / "data" / "tiny")["law_check"]["diverged"] == 1
    db.close()


def test_real_rig_runs_in_process_one_run_at_a_time(project):
    register_rig("inprocess-motor", "test_campaign_support:InProcessMotor")
    write(project / "rigs" / "bench.toml", MOTOR_RIG.replace('kind = "dcmotor"', 'kind = "inprocess-motor"'))
    path = write(project / "bench.toml", campaign_text(name="bench", rig="rigs/bench.toml"))
    assert main(["run", str(path), "--workers", "4"]) == 0
    rows = ledger_rows(project / "data" / "bench")
    assert len(rows) == 9 and {r["state"] for r in rows} <= {"done", "aborted"}
    assert {r["pid"] for r in rows} == {os.getpid()}  # no worker process
    assert len({r["finished_at"] for r in rows}) == 9  # batches of one run


@pytest.mark.slow
def test_second_runner_refused_and_sigint_leaves_a_resumable_campaign(project):
    grid = '"controller.gamma" = { log10 = [1.5, 3.0], num = 8 }\n"controller.k_p" = { log10 = [0.0, 2.0], num = 8 }'
    # 30 s runs: the campaign must outlast the three commands below (at 5 s it had finished, 64 of 64 in
    # 3 s, before the Ctrl-C came on an idle machine)
    write(project / "long.toml", campaign_text(name="long", grid=grid, duration=30.0))
    first = spawn("run", "long.toml", "--workers", "1", "--batch-size", "2", cwd=project)
    directory = project / "data" / "long"
    assert wait_for(lambda: sum(r["state"] in TERMINAL for r in ledger_rows(directory)) >= 2, 60), first.communicate()
    st = json.loads(cli("status", "data/long", "--json", cwd=project).stdout)
    assert st["running"] == {"host": socket.gethostname(), "pid": first.pid} and st["total"] == 64
    second = cli("resume", "data/long", cwd=project)
    assert second.returncode == 1
    assert f"host {socket.gethostname()} PID {first.pid}" in second.stderr
    again = cli("run", "long.toml", cwd=project)
    assert again.returncode == 1 and "labrunner resume data/long" in again.stderr
    os.killpg(first.pid, signal.SIGINT)  # Ctrl-C in a terminal reaches the whole process group
    out, err = first.communicate(timeout=60)
    assert first.returncode == 130, err
    assert "interrupted" in err and "labrunner resume data/long" in err
    rows = ledger_rows(directory)
    states = [r["state"] for r in rows]
    assert (
        states.count("claimed") == 0 and states.count("planned") > 0
    )  # none left claimed: stopped batches went back to planned
    done = cli("resume", "data/long", "--workers", "2", cwd=project)
    assert done.returncode == 0, done.stderr
    rows = ledger_rows(directory)
    assert len(rows) == 64 and {r["state"] for r in rows} <= {"done", "aborted"}
    assert all(r["attempts"] == 1 for r in rows)  # nothing ran twice


@pytest.mark.slow
def test_process_pool_and_dask_cluster_give_identical_ledgers(project):
    from distributed import LocalCluster

    grid = '"controller.gamma" = { log10 = [1.0, 3.0], num = 5 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 5 }'
    path = write(project / "twin.toml", campaign_text(name="twin", grid=grid))
    assert main(["run", str(path), "--out", "pool", "--workers", "2", "--batch-size", "4"]) == 0
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        args = ["run", str(path), "--out", "dask", "--workers", "2", "--batch-size", "4"]
        assert main([*args, "--executor", cluster.scheduler_address]) == 0
    pool, dask = ledger_rows(project / "pool"), ledger_rows(project / "dask")
    assert len(pool) == 25 and {r["pid"] for r in dask}.isdisjoint({os.getpid()})
    assert comparable(pool) == comparable(dask)
    assert {r["state"] for r in pool} >= {"done", "aborted"}  # the comparison covers both kinds of outcome


def test_rig_failure_stops_the_campaign_and_resume_continues(project, capsys):
    register_rig("busoff-motor", "test_campaign_support:BusOffMotor")
    write(project / "rigs" / "busoff.toml", MOTOR_RIG.replace('kind = "dcmotor"', 'kind = "busoff-motor"'))
    path = write(project / "bus.toml", campaign_text(name="bus", rig="rigs/busoff.toml"))
    assert main(["run", str(path)]) == 1
    err = capsys.readouterr().err
    assert "stopped: rig" in err and "CAN bus off" in err and "labrunner resume data/bus" in err
    states = [r["state"] for r in ledger_rows(project / "data" / "bus")]
    assert states.count("failed") == 1 and states.count("planned") == 8  # the rig was left safe, the rest waits
    failed = next(r for r in ledger_rows(project / "data" / "bus") if r["state"] == "failed")
    assert "CAN bus off" in json.loads(failed["outcome_json"])["message"]
    capsys.readouterr()
    assert main(["resume", "data/bus"]) == 1  # resume goes on with the next point (and the bus fails again)
    states = [r["state"] for r in ledger_rows(project / "data" / "bus")]
    assert states.count("failed") == 2 and states.count("planned") == 7


#: The campaign file of issue 6, verbatim (its [grid] shortened to four points below).
ISSUE_EXAMPLE = """\
[campaign]
name = "quickstart"          # [a-z0-9_-]+
description = "γ–k_p sweep of first-order MFC on the simulated DC motor"
rig = "dcmotor-sim"          # rigs/<name>.toml, or a path
fs = 200.0                   # Hz
duration = 5.0               # s; default: the reference's length
seed = 0

[controller]                 # kind: mfc1 | mfc2 | open-loop | valve-ffc | plate-mbc | ...
kind = "mfc1"
output = "velocity"          # for the motor: velocity | angle
gamma = 108.55
k_p = 50.0

[differentiator]
alpha = 9
beta = 9
N = 0
omega_c = 200.0
method = "midpoint"

[reference]
kind = "setpoints"
levels = [0.0, 20.0, 0.0]    # in the output's unit
transition = 1.0
hold = 1.0

[safety]
max_du_dt = 120.0

[grid]                       # axes over dotted keys of this file
"controller.gamma" = { log10 = [0.0, 4.0], num = 17 }
"controller.k_p" = { log10 = [-1.0, 3.0], num = 17 }

[derived]                    # safe arithmetic over grid keys and constants; no eval
# "controller.k_d" = "0.5 * controller.k_p"
"""


def test_issue_example_plans_its_289_points_with_every_key():
    from labrunner.campaign import spec

    campaign = spec.from_text(ISSUE_EXAMPLE)
    points, _ = spec.plan(campaign)
    assert len(points) == 17 * 17
    gammas = sorted({p.parameters["controller.gamma"] for p in points})
    k_ps = sorted({p.parameters["controller.k_p"] for p in points})
    assert gammas == pytest.approx([10 ** (i / 4) for i in range(17)], rel=1e-12)  # 10^a … 10^b, a, b exponents
    assert k_ps == pytest.approx([10 ** (-1 + i / 4) for i in range(17)], rel=1e-12)
    assert {p.batch_key for p in points} == {points[0].batch_key}
    assert json.loads(points[0].batch_key)[1:3] == [200.0, 5.0]
    config = campaign.resolve(points[0].parameters)
    assert config["campaign"] == {"name": "quickstart", "rig": "dcmotor-sim", "fs": 200.0, "duration": 5.0, "seed": 0}
    assert config["differentiator"] == {"alpha": 9, "beta": 9, "N": 0, "omega_c": 200.0, "method": "midpoint"}
    assert config["reference"] == {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 1.0, "hold": 1.0}
    assert config["safety"] == {"max_du_dt": 120.0} and config["controller"]["output"] == "velocity"
    # the commented [derived] line, switched on for the second-order MFC it belongs to
    second = ISSUE_EXAMPLE.replace('kind = "mfc1"\noutput = "velocity"', 'kind = "mfc2"\noutput = "angle"\nk_d = 1.0')
    second = second.replace('# "controller.k_d"', '"controller.k_d"').replace("num = 17", "num = 3")
    for p in spec.plan(spec.from_text(second))[0]:
        assert p.parameters["controller.k_d"] == 0.5 * p.parameters["controller.k_p"]


def test_issue_example_runs_and_its_ledger_rows_agree_with_the_logs(project, capsys):
    """Every key of the example reaches the runs, and every ledger column of issue 6 holds what
    the run's log says, recomputed here from the logged signals."""
    import sqlite3
    import time

    import numpy as np

    from labrunner.campaign import spec

    grid = '"controller.k_p" = { values = [10.0, 1000.0] }\n"campaign.seed" = { values = [0, 1] }\n'
    text = ISSUE_EXAMPLE.split("[grid]")[0] + "[grid]\n" + grid
    path = write(project / "issue.toml", text)
    t0 = time.time()
    assert main(["run", str(path), "--workers", "2"]) == 0
    directory = project / "data" / "quickstart"
    rows = ledger_rows(directory)
    assert len(rows) == 4
    by_key = {}
    for row in rows:
        params = json.loads(row["parameters"])
        by_key[(params["controller.k_p"], params["campaign.seed"])] = row
        log = read_run(directory / row["log_path"])
        assert row["log_path"] == f"runs/{row['id']}.mcap" and log.metadata["parameters"] == params
        assert log.metadata["config"]["reference"] == {
            "kind": "setpoints",
            "levels": [0.0, 20.0, 0.0],
            "transition": 1.0,
            "hold": 1.0,
        }
        assert log.metadata["run"]["seed"] == params["campaign.seed"] and log.fs == 200.0
        e, u = log.frame["e_omega"].to_numpy(), log.frame["u"].to_numpy()
        assert row["rms_error"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
        assert row["input_energy"] == pytest.approx(np.sum(u**2), rel=1e-12)
        assert row["max_abs_input"] == pytest.approx(np.max(np.abs(u)), rel=1e-12)
        outcome = json.loads(row["outcome_json"])
        assert outcome["status"] == row["outcome"] == log.outcome["status"]
        assert row["attempts"] == 1 and row["host"] == socket.gethostname() and row["pid"] != os.getpid()
        assert t0 <= row["claimed_at"] <= row["finished_at"] <= time.time()
        assert row["engine_s"] > 0 and row["write_s"] > 0 and row["publish_s"] >= 0
        if row["outcome"] == "completed":
            assert log.n_samples == 1000  # duration 5 s at 200 Hz
        else:  # the safety routine's |du/dt| ≥ 120 V/s of [safety]
            assert row["state"] == "aborted"
            assert outcome["monitor"] == "du_dt" and outcome["threshold"] == 120.0 and outcome["value"] >= 120.0
            assert outcome["time"] == pytest.approx((log.n_samples - 1) / 200.0)
    assert by_key[(10.0, 0)]["outcome"] == by_key[(10.0, 1)]["outcome"] == "completed"
    assert by_key[(1000.0, 0)]["outcome"] == "aborted"
    assert by_key[(10.0, 0)]["rms_error"] != by_key[(10.0, 1)]["rms_error"]  # the seed sets the noise
    db = sqlite3.connect(directory / "ledger.sqlite")
    meta = dict(db.execute("SELECT key, value FROM meta"))
    assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    db.close()
    assert meta["campaign_file"] == text == (directory / "campaign.toml").read_text()
    assert meta["plan_checksum"] == spec.plan(spec.load(path))[1]
    capsys.readouterr()
    assert main(["status", str(directory), "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert {"campaign", "total", "outcomes", "elapsed_s", "estimate_s"} <= set(st)
    words = [r["outcome"] or r["state"] for r in rows]
    assert st["total"] == 4 and st["outcomes"] == {
        w: words.count(w) for w in ("completed", "no-motion", "aborted", "failed", "claimed", "planned")
    }
    assert st["campaign"] == "quickstart" and st["estimate_s"] == 0.0 and 0 < st["elapsed_s"] < time.time() - t0


def test_dry_run_of_an_existing_campaign_says_run_would_refuse(project, capsys):
    path = write(project / "tiny.toml", campaign_text(grid='"controller.k_p" = { values = [10.0] }'))
    assert main(["run", str(path)]) == 0
    capsys.readouterr()
    assert main(["run", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "1 points" in out and "note: `labrunner run` would refuse" in out and "labrunner resume data/tiny" in out
    path.write_text(path.read_text().replace("values = [10.0]", "values = [20.0]"))
    assert main(["run", str(path)]) == 1  # same name, other grid: not "this campaign"
    err = capsys.readouterr().err
    assert "planned from another version of this file" in err and "--out" in err and err.count("\n") == 1


def test_default_workers_are_all_cores():
    from labrunner.campaign.executors import open_executor

    with open_executor(real_rig=False, workers=None, url=None) as handle:
        assert handle.slots == len(os.sched_getaffinity(0)) == handle.executor._max_workers


_INTERRUPTED_SHUTDOWN = """
import os, signal
from concurrent.futures import ProcessPoolExecutor
from labrunner.campaign.executors import open_executor
shutdown = ProcessPoolExecutor.shutdown
def pressed(self, *args, **kwargs):
    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while the pool shuts down
    return shutdown(self, *args, **kwargs)
ProcessPoolExecutor.shutdown = pressed
try:
    with open_executor(real_rig=False, workers=2, url=None) as handle:
        pids = list(handle.executor._processes)
except KeyboardInterrupt:
    gone = []
    for pid in pids:
        try:
            os.kill(pid, 0)
            gone.append(False)
        except ProcessLookupError:
            gone.append(True)
    print("interrupted", gone)
"""


def test_a_ctrl_c_while_the_pool_shuts_down_waits_until_its_workers_are_down():
    """The pool outlives the runner's signal handling (it is opened before the plan): a Ctrl-C
    during its shutdown is held until the workers are joined, then raised; the process exits
    (it hung in multiprocessing's exit handler, joining workers nobody had stopped)."""
    out = subprocess.run([sys.executable, "-c", _INTERRUPTED_SHUTDOWN], capture_output=True, text=True, timeout=60)
    assert out.stdout.split("\n")[0] == "interrupted [True, True]", out.stderr


def _worker_modules() -> list[str]:
    from labrunner.campaign.executors import WORKER_MODULES

    return [m for m in WORKER_MODULES if m in sys.modules]


def test_the_pool_forks_its_workers_when_opened_and_they_load_the_engine_themselves():
    """The runner opens the pool before it validates the points: every worker exists at once and
    imports what a batch needs in its initializer, before its first task."""
    from labrunner.campaign.executors import WORKER_MODULES, open_executor

    with open_executor(real_rig=False, workers=2, url=None) as handle:
        assert len(handle.executor._processes) == 2
        assert handle.executor.submit(_worker_modules).result() == list(WORKER_MODULES)


def test_each_log_is_written_fsynced_and_renamed_before_its_row_is_committed(project, monkeypatch):
    """Issue 6: "publishes its MCAP atomically (temp name, fsync, rename) and then commits its row".
    A real rig runs in this process, so every step is observed in order."""
    from pathlib import Path

    from labrunner.campaign import worker
    from labrunner.campaign.ledger import Ledger

    register_rig("inprocess-motor", "test_campaign_support:InProcessMotor")
    write(project / "rigs" / "bench.toml", MOTOR_RIG.replace('kind = "dcmotor"', 'kind = "inprocess-motor"'))
    path = write(project / "bench.toml", campaign_text(name="order", rig="rigs/bench.toml"))
    events: list[tuple[str, str]] = []
    fsync, fsync_dir, replace, commit = worker._fsync, worker.fsync_dir, os.replace, Ledger.commit

    def on_replace(src, dst):
        if Path(dst).parent.name == "runs":
            events.append(("rename", f"{Path(src).name}>{Path(dst).name}"))
        return replace(src, dst)

    def on_commit(self, *records, **kw):
        for record in records:
            final = self.directory / record.log_path
            assert final.is_file() and not list(final.parent.glob(f".tmp-{record.point_id}-*"))
            events.append(("commit", record.point_id))
        return commit(self, *records, **kw)

    monkeypatch.setattr(worker, "_fsync", lambda p: (events.append(("fsync", Path(p).name)), fsync(p))[1])
    monkeypatch.setattr(worker, "fsync_dir", lambda d: (events.append(("fsync_dir", Path(d).name)), fsync_dir(d))[1])
    monkeypatch.setattr(os, "replace", on_replace)
    monkeypatch.setattr(Ledger, "commit", on_commit)
    assert main(["run", str(path)]) == 0
    rows = ledger_rows(project / "data" / "order")
    assert len(rows) == 9
    for row in rows:
        pid = row["id"]
        synced = next(i for i, (k, v) in enumerate(events) if k == "fsync" and v.startswith(f".tmp-{pid}-"))
        tmp = events[synced][1]
        renamed = events.index(("rename", f"{tmp}>{pid}.mcap"))
        dir_synced = next(i for i, (k, v) in enumerate(events) if k == "fsync_dir" and v == "runs" and i > renamed)
        assert synced < renamed < dir_synced < events.index(("commit", pid))
