"""Issue 28: inputs that validation passes must run, analysis must take every grid that run takes,
logs prove their point, and the messages of the first hour say what is true.

The one-line refusals are in tests/test_hostile_inputs.py; here what is accepted must work."""

from __future__ import annotations

import io
import json
import math
import resource
import shutil
import sqlite3
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from test_campaign_support import MOTOR_RIG, campaign_text, cli, ledger_rows, write

from labrunner.analysis.map_data import cell_edges
from labrunner.analysis.overlays import Theory, dense_axis, gamma_kp_lines, kp_kd_lines, sweep_lines, transitions
from labrunner.campaign import runner
from labrunner.cli import main
from labrunner.metrics import Roles, run_metrics

MOTOR = {"a": 39.44, "b": 108.55}


@pytest.fixture
def project(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(tmp_path / "rigs" / "motor.toml", MOTOR_RIG)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _run(project: Path, name: str, **kw) -> Path:
    path = write(project / f"{name}.toml", campaign_text(name, **kw))
    assert main(["run", str(path), "--workers", "1"]) == 0
    return project / "data" / name


# -- inputs validation passes: the runs must not fail -------------------------------------------


def test_a_window_ending_far_past_the_run_and_the_largest_seed_run_without_a_failure(project):
    grid = '"controller.k_p" = { values = [10.0, 50.0] }'
    extra = "\n[metrics]\nrest = [0.5, 1e308]\nall = [0.0, 1.0]\n"
    directory = _run(project, "w", grid=grid, duration=1.0, seed=2**63 - 1, extra=extra)
    rows = ledger_rows(directory)
    assert {r["outcome"] for r in rows} <= {"completed", "no-motion", "aborted"}
    for r in rows:  # [0, 1] s is the whole run: the same metrics as the run's own
        m = json.loads(r["metrics_json"])
        assert m["rms_error@all"] == pytest.approx(m["rms_error"])
        assert math.isfinite(m["rms_error@rest"])


@pytest.mark.parametrize("t1", [1.0, 2.0, 1e10, 1e300, 1e308, 1.7976931348623157e308])
def test_window_indices_past_the_end_cover_the_rest_of_the_run(t1):
    # reference: the plain slice from ceil(t0·fs) to the end of the run
    fs, k = 200.0, 200
    rng = np.random.default_rng(0)
    signals = {"e": rng.normal(size=k), "u": rng.normal(size=k)}
    roles = Roles(errors=("e",), inputs=("u",))
    out = run_metrics(signals, roles, fs=fs, windows={"w": (0.25, t1)})
    assert out["rms_error@w"] == pytest.approx(float(np.sqrt(np.mean(signals["e"][50:] ** 2))))


# -- analysis on any grid run accepts ------------------------------------------------------------


@pytest.mark.parametrize("seed", range(40))
def test_overlays_on_random_linear_grids_near_the_domain_edge(seed):
    # property-style: random linear gamma, k_p and k_d axes whose drawn extent (half a cell beyond
    # the last values) leaves gamma > 0 and k_d >= 0; the theory gives lines (NaN outside) or
    # nothing, never an error, and the same bounds as inside wherever it is defined
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    gammas = np.sort(rng.uniform(1e-3, 400.0, n)) if seed % 2 else np.linspace(rng.uniform(1e-3, 5), 300.0, n)
    k_ds = np.sort(np.r_[0.0, rng.uniform(0.0, 50.0, n - 1)])
    theory = Theory("mfc1", 0.035, MOTOR)
    dense = dense_axis(cell_edges(gammas, False), False)
    lines = gamma_kp_lines(theory, dense)
    bound = next(line for line in lines if line.gid == "bound:mfc1-motor:k_p_max")
    inside = dense > 0
    assert np.all(np.isnan(bound.y[~inside]))
    assert np.array_equal(np.isfinite(bound.y[inside]), np.isfinite(theory.k_p_limits("mfc1-motor", dense[inside])[1]))
    mfc2 = Theory("mfc2", 0.035, MOTOR)
    kd_dense = dense_axis(cell_edges(k_ds, False), False)
    kp_kd_lines(mfc2, float(gammas[-1]), kd_dense)  # k_d < 0 below the first value: no error
    assert sweep_lines(theory, "gamma", dense, {"gamma": 1.0, "k_p": 10.0}) is not None
    for gamma in (float(dense[0]), float(gammas[0])):  # no prediction exactly where gamma <= 0
        assert (theory.predict("mfc1-motor", {"gamma": gamma, "k_p": 1.0}) is None) == (gamma <= 0)


def test_transitions_skip_values_without_a_theory():
    values = np.array([-2.0, -1.0, 1.0, 2.0, 4.0])
    flags = {-2.0: None, -1.0: None, 1.0: True, 2.0: True, 4.0: False}
    assert transitions(values, flags.get) == [pytest.approx(math.sqrt(8.0))]


@pytest.mark.parametrize(
    "grid",
    [
        '"controller.gamma" = { values = [1.0, 150.0, 300.0] }\n"controller.k_p" = { values = [0.0, 20.0, 40.0] }',
        '"controller.gamma" = { linspace = [0.5, 200.0], num = 3 }\n"controller.k_p" = { values = [5.0, 10.0] }',
        '"controller.gamma" = { values = [0.01, 400.0] }',
    ],
)
def test_analyse_takes_a_grid_whose_map_reaches_outside_the_theory(project, grid):
    directory = _run(project, "dom", grid=grid, duration=1.0)
    assert main(["analyse", str(directory)]) == 0
    assert (directory / "report" / "index.html").is_file()


# -- a log proves which point it belongs to ------------------------------------------------------


def test_swapped_logs_are_foreign_in_the_table_and_the_report_until_swapped_back(project, capsys):
    directory = _run(project, "sw", grid='"controller.k_p" = { values = [10.0, 50.0, 90.0] }', duration=1.0)
    a, b = sorted((directory / "runs").glob("*.mcap"))[:2]

    def swap() -> None:
        a.rename(a.with_suffix(".tmp"))
        b.rename(a)
        a.with_suffix(".tmp").rename(b)

    assert main(["analyse", str(directory)]) == 0  # proved once: cached by size and mtime
    swap()
    capsys.readouterr()
    assert main(["analyse", str(directory)]) == 0
    printed = capsys.readouterr()
    assert f"foreign: runs/{a.name}: point {a.stem}: the log is point {b.stem}'s run" in printed.out + printed.err
    table = {r["id"]: r for r in _csv(directory / "report" / "metrics.csv")}
    assert table[a.stem]["log_state"] == table[b.stem]["log_state"] == "foreign"
    assert sum(r["log_state"] == "ok" for r in table.values()) == 1
    html = (directory / "report" / "index.html").read_text()
    assert f'href="../runs/{a.name}"' not in html and "foreign log" in html
    swap()
    assert main(["analyse", str(directory)]) == 0
    assert {r["log_state"] for r in _csv(directory / "report" / "metrics.csv")} == {"ok"}


def test_a_copied_log_is_foreign_even_with_an_equal_size(project, capsys):
    directory = _run(project, "cp", grid='"controller.k_p" = { values = [10.0, 50.0] }', duration=1.0)
    a, b = sorted((directory / "runs").glob("*.mcap"))
    shutil.copyfile(b, a)  # same content, a fresh mtime: nothing cached can vouch for it
    assert main(["analyse", str(directory), "--recompute"]) == 0
    table = {r["id"]: r for r in _csv(directory / "report" / "metrics.csv")}
    assert table[a.stem]["log_state"] == "foreign" and table[b.stem]["log_state"] == "ok"


def _csv(path: Path) -> list[dict]:
    import csv

    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# -- messages of the first hour -------------------------------------------------------------------


def test_repair_leaves_a_sound_ledger_alone_and_force_rebuilds_it(project, capsys):
    directory = _run(project, "r", duration=1.0)
    before = (directory / "ledger.sqlite").read_bytes()
    capsys.readouterr()
    assert main(["repair", str(directory)]) == 2
    assert "is sound" in capsys.readouterr().err
    assert (directory / "ledger.sqlite").read_bytes() == before and not (directory / "quarantine").exists()
    assert main(["repair", "--force", str(directory)]) == 0
    assert main(["analyse", str(directory)]) == 0
    printed = capsys.readouterr()
    assert "ledger replaced by repair" in printed.out + printed.err and "point None" not in printed.out + printed.err


def test_resume_with_nothing_to_do_prints_its_line_once_without_a_question_mark(project):
    _run(project, "n", duration=1.0)
    done = cli("resume", "data/n", cwd=project)
    assert done.returncode == 0
    lines = [line for line in done.stderr.splitlines() if line.startswith("n: ")]
    assert len(lines) == 1 and "ETA 0:00" in lines[0], done.stderr


def test_a_guided_run_reports_the_outcomes_status_counts(tmp_path):
    from test_guided_support import write_campaign

    polack = {"procedure": "polack", "gamma_start": 1e4, "gamma_stop": 1.0, "kp_start": 0.1, "kp_stop": 1e3}
    path = write_campaign(tmp_path, {**polack, "per_decade": 2}, name="pol")
    out, directory = runner.start(path, tmp_path / "run", runner.Options(workers=1, stream=io.StringIO()))
    counted = Counter(r["outcome"] for r in ledger_rows(Path(directory)))
    assert {k: v for k, v in out.counts.items() if v} == dict(counted)
    assert sum(counted.values()) > 1


def test_a_log_the_file_system_refuses_is_named_in_the_message(project):
    # a file-size limit below one log (20 s at 1 kHz) and above the ledger: the log write fails
    text = campaign_text("big", grid='"controller.k_p" = { values = [10.0] }', duration=20.0)
    write(project / "big.toml", text.replace("fs = 200.0", "fs = 1000.0"))
    limit = 200_000

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    done = cli("run", "big.toml", "--workers", "1", cwd=project, preexec_fn=small_files)
    err = done.stderr.strip().splitlines()[-1]
    assert done.returncode == 1, done.stderr
    assert f"cannot write the run log {project / 'data' / 'big' / 'runs'}/.tmp-" in err
    assert ".mcap: File too large (disk full or file-size limit); continue with `labrunner resume data/big`" in err
    assert "of batch" not in err


def test_runs_being_a_file_is_named_with_the_way_out(project, capsys):
    directory = _run(project, "rf", duration=1.0)
    shutil.rmtree(directory / "runs")
    (directory / "runs").write_text("oops\n")
    capsys.readouterr()
    assert main(["resume", str(directory)]) == 1
    assert "runs is a file, not the directory of the campaign's run logs: move it away" in capsys.readouterr().err
    assert not (directory / "quarantine").exists()
    db = sqlite3.connect(directory / "ledger.sqlite")
    assert db.execute("SELECT COUNT(*) FROM sessions").fetchone()[0] == 1  # resume started no session
