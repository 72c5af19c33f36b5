"""``labrunner run / resume / status`` end to end on the simulated DC motor (real engine, real logs)."""

from __future__ import annotations

import json
import os
import signal
import socket
import tomllib

import pytest

from labrunner.cli import main
from labrunner.logs import read_run
from labrunner.rigs.registry import register_rig
from labrunner.rigs.sim.dcmotor import DCMotorTwin
from test_campaign_support import (  # noqa: F401 - fixture
    MOTOR_RIG,
    campaign_text,
    cli,
    comparable,
    ledger_rows,
    project,
    spawn,
    wait_for,
    write,
)

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
    assert st["campaign"] == "tiny" and st["total"] == 9 and st["planned"] == st["claimed"] == 0
    assert st["done"] + st["aborted"] + st["failed"] == 9 and st["elapsed_s"] > 0 and st["running"] is None
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


def test_resume_refuses_an_edited_campaign_file_but_not_a_comment(project, capsys):
    path = write(project / "tiny.toml", campaign_text(grid='"controller.k_p" = { values = [10.0, 20.0] }'))
    assert main(["run", str(path)]) == 0
    path.write_text("# only a comment\n" + path.read_text())
    assert main(["resume", "data/tiny"]) == 0
    path.write_text(path.read_text().replace("values = [10.0, 20.0]", "values = [10.0, 30.0]"))
    capsys.readouterr()
    assert main(["resume", "data/tiny"]) == 1
    err = capsys.readouterr().err
    assert "was edited since this campaign was planned" in err and err.count("\n") == 1


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
    write(project / "long.toml", campaign_text(name="long", grid=grid, duration=5.0))
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
    assert states.count("claimed") == 0 and states.count("planned") > 0  # running batches finished and committed
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
