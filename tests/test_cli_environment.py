"""Issue 36: a hostile environment gets one clear line and a non-zero exit, never a traceback:
names that are not UTF-8 (and the internal-error handler with such an argv), ``status`` with
stdout closed, ``run`` from a deleted working directory, and ``analyse`` filling the disk (the
file named, the advice to run analyse again, not resume; no temporary file left)."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_campaign_support import ROOT, campaign_text, write

from labrunner.cli import _write_traceback, main

GRID = '"controller.k_p" = { values = [1.0, 10.0] }'


def _cli(args: list[str], cwd: Path, **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "labrunner", *args], cwd=cwd, env=env, capture_output=True, timeout=120, **kw
    )


def _one_line(err: bytes) -> str:
    text = err.decode("utf-8", "backslashreplace")
    assert text.count("\n") == 1 and "Traceback" not in text and "internal error" not in text, text
    return text


def test_a_campaign_file_named_in_bytes_that_are_not_utf8_is_refused(project):
    name = os.fsdecode(b"c\xff.toml")
    write(project / name, campaign_text("c", grid=GRID, duration=0.5))
    before = sorted(os.listdir(project))
    done = _cli(["run", name, "--out", "out"], project)
    assert done.returncode == 2
    assert "must be a path of valid UTF-8" in _one_line(done.stderr)
    assert sorted(os.listdir(project)) == before


def test_a_project_folder_whose_name_is_not_utf8_is_refused_before_anything_is_made(project):
    folder = project / os.fsdecode(b"lab\xfe")
    folder.mkdir()
    (folder / "rigs").mkdir()
    (folder / "rigs" / "motor.toml").write_text((project / "rigs" / "motor.toml").read_text())
    write(folder / "c.toml", campaign_text("c", grid=GRID, duration=0.5))
    done = _cli(["run", "c.toml"], folder)
    assert done.returncode == 2
    line = _one_line(done.stderr)
    assert "is not valid UTF-8" in line and "rename the file or folder" in line and len(line) < 300
    assert sorted(os.listdir(folder)) == ["c.toml", "rigs"]


def test_the_internal_error_handler_survives_an_argv_that_is_not_utf8():
    try:
        raise RuntimeError("a bug")
    except RuntimeError:
        where = _write_traceback("run", ["run", os.fsdecode(b"c\xff.toml")])
    text = Path(where).read_text(encoding="utf-8")
    Path(where).unlink()
    assert "c\\udcff.toml" in text and "RuntimeError: a bug" in text


def test_status_with_stdout_closed_says_so(project):
    done = _cli(["status", "anything"], project, preexec_fn=lambda: os.close(1))
    assert done.returncode == 1
    assert "standard output is closed" in _one_line(done.stderr)


def test_run_from_a_deleted_working_directory_says_so(project):
    path = write(project / "c.toml", campaign_text("c", grid=GRID, duration=0.5))
    gone = project / "gone"
    gone.mkdir()

    def enter_and_delete() -> None:
        os.chdir(gone)
        os.rmdir(gone)

    done = _cli(["run", str(path), "--out", str(project / "out")], project, preexec_fn=enter_and_delete)
    assert done.returncode == 1
    assert "the working directory no longer exists" in _one_line(done.stderr)
    assert not (project / "out").exists()


@pytest.fixture
def finished(project) -> Path:
    path = write(project / "c.toml", campaign_text("c", grid=GRID, duration=0.5))
    assert main(["run", str(path), "--workers", "1"]) == 0
    return project / "data" / "c"


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("filling", ["metrics.csv", "sweep.png"])
def test_analyse_filling_the_disk_names_the_file_and_leaves_no_temporary_file(finished, capsys, monkeypatch, filling):
    import matplotlib.figure
    import pandas as pd

    if filling == "metrics.csv":
        monkeypatch.setattr(pd.DataFrame, "to_csv", _disk_full)
    else:

        def half_written(self, path, **kwargs):
            Path(path).write_bytes(b"\x89PNG half")
            _disk_full()

        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", half_written)
    code = main(["analyse", str(finished)])
    err = capsys.readouterr().err.splitlines()[-1]
    assert code == 1
    assert err.startswith(f"labrunner analyse: error: {finished / 'report' / filling}: No space left on device"), err
    assert "run `labrunner analyse` again" in err and "resume" not in err
    left = [p.name for p in (finished / "report").rglob("*") if p.name.endswith(".tmp")]
    assert left == []
