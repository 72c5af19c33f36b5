"""Issue 18: every malformed input the suite tries, from one table (tests/data/malformed_inputs.toml).

Each case is a campaign file (the table's base campaign with text replaced or appended) given to
``labrunner run``, or a command line run in a project that holds a finished campaign, two bad rig
files (rigs/bad.toml: a negative parameter; rigs/badfault.toml: a fault of the wrong length), damaged
copies of its ledger, foreign MCAP files and a few odd files. Every case must exit with its code
(2, or 1 where the table says: an environment or a refused campaign directory), print exactly
the table's one line on stderr, and create nothing. Cases run in-process through ``main()``; the
few marked ``subprocess`` run the real program."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from labrunner.cli import main

TABLE = Path(__file__).parent / "data" / "malformed_inputs.toml"
ROOT = Path(__file__).resolve().parents[1]
DAMAGES = (
    "garbage",
    "truncated",
    "foreign",
    "empty",
    "deleted-rows",
    "added-row",
    "bad-parameters",
    "bad-count",
    "ids-changed",
    "no-meta-keys",
    "schema-version",
)


def load_table() -> dict:
    with open(TABLE, "rb") as fh:
        return tomllib.load(fh)


def campaign_file(base: str, case: dict) -> str:
    text = base
    for old, new in case.get("replace", []):
        assert old in text, f"{case['name']}: {old!r} is not in the base campaign"
        text = text.replace(old, new, 1)
    return text + case.get("append", "")


def _damage(directory: Path, kind: str) -> None:
    path = directory / "ledger.sqlite"
    if kind in ("garbage", "empty", "truncated"):
        data = path.read_bytes()
        path.write_bytes({"garbage": os.urandom(len(data)), "empty": b"", "truncated": data[: len(data) // 2]}[kind])
        return
    if kind == "foreign":
        path.unlink()
        db = sqlite3.connect(path)
        db.execute("CREATE TABLE things (x)")
        db.commit()
        db.close()
        return
    statements = {
        "deleted-rows": "DELETE FROM points WHERE seq = 1",
        "added-row": "INSERT INTO points (seq, id, parameters, batch_key) VALUES (99, 'extra', '{}', 'k')",
        "bad-parameters": "UPDATE points SET parameters = '{not json' WHERE seq = 0",
        "bad-count": "UPDATE meta SET value = 'many' WHERE key = 'points'",
        "ids-changed": "UPDATE points SET id = 'ffffffffffffffff' WHERE seq = 0",
        "no-meta-keys": "DELETE FROM meta WHERE key = 'points'",
        "schema-version": "UPDATE meta SET value = '99' WHERE key = 'schema_version'",
    }
    db = sqlite3.connect(path)
    db.execute(statements[kind])
    db.commit()
    db.close()


def _foreign_mcaps(project: Path) -> None:
    from mcap.writer import Writer

    for name, channels, run in (
        ("foreign-channels.mcap", {"a": "1"}, None),
        ("foreign-roles.mcap", {"a": json.dumps({"role": 5, "unit": [1]})}, None),
        ("foreign-fs.mcap", {"a": json.dumps({"role": "output"})}, {"fs": json.dumps("abc")}),
    ):
        with open(project / name, "wb") as fh:
            writer = Writer(fh)
            writer.start()
            writer.add_metadata("channels", channels)
            if run is not None:
                writer.add_metadata("run", run)
            writer.finish()


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict:
    """The project every case runs in (shared: cases must not change it, which each one checks)."""
    return build_world(tmp_path_factory.mktemp("malformed"))


def build_world(project: Path) -> dict:
    table = load_table()
    (project / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (project / "rigs").mkdir()
    (project / "rigs" / "motor.toml").write_text(table["rig"])
    (project / "rigs" / "bad.toml").write_text(table["rig"].replace("a = 39.44", "a = -1.0"))
    (project / "rigs" / "badfault.toml").write_text(table["rig"] + "\n[faults]\nt_start = 1\nsensor_step = [1, 2]\n")
    (project / "c.toml").write_text(table["base"])
    (project / "afile").write_text("not a campaign\n")
    (project / "notempty").mkdir()
    (project / "notempty" / "notes.txt").write_text("mine\n")
    (project / "empty-dir").mkdir()
    (project / "binary.toml").write_bytes(b"\xff\xfe\x00\x81garbage")
    _foreign_mcaps(project)
    cwd = os.getcwd()
    os.chdir(project)
    try:
        assert main(["run", "c.toml", "--out", "done", "--workers", "1"]) == 0
    finally:
        os.chdir(cwd)
    for kind in DAMAGES:
        shutil.copytree(project / "done", project / f"damaged-{kind}")
        _damage(project / f"damaged-{kind}", kind)
    log = sorted((project / "done" / "runs").glob("*.mcap"))[0].name
    return {"project": project, "table": table, "log": log}


def _tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every path under ``root`` with its size and mtime, but SQLite's own -wal/-shm files (a read-only
    connection to a ledger in WAL mode makes them, and cannot remove them)."""
    out = {}
    for path in root.rglob("*"):
        if "__pycache__" not in path.parts and not path.name.endswith(("-wal", "-shm")):
            st = path.lstat()
            out[str(path.relative_to(root))] = (0, 0) if path.is_dir() else (st.st_size, st.st_mtime_ns)
    return out


def run_case(world: dict, args: list[str], *, program: bool = False) -> tuple[int, str]:
    """Exit code and stderr of ``labrunner ARGS`` in the world's project (its path written PROJECT,
    the checkout's ROOT, so that the table's lines do not depend on where the test runs)."""
    code, err = _run(world, [a.replace("LOG", world["log"]) for a in args], program)
    return code, err.replace(str(world["project"]), "PROJECT").replace(str(ROOT), "ROOT")


def _run(world: dict, args: list[str], program: bool) -> tuple[int, str]:
    project = world["project"]
    if program:
        done = subprocess.run(
            [sys.executable, "-m", "labrunner", *args], cwd=project, capture_output=True, text=True, timeout=120
        )
        return done.returncode, done.stderr
    cwd = os.getcwd()
    os.chdir(project)
    try:
        err, out = io.StringIO(), io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                code = main(args)
            except SystemExit as exc:  # argparse
                code = exc.code
        return int(code), err.getvalue()
    finally:
        os.chdir(cwd)


def _cases() -> list:
    table = load_table()
    out = [pytest.param("campaign", c, id=f"campaign: {c['name']}") for c in table["campaign"]]
    out += [pytest.param("command", c, id=f"command: {c['name']}") for c in table["command"]]
    return out


def test_the_table_holds_at_least_200_cases():
    table = load_table()
    assert len(table["campaign"]) + len(table["command"]) >= 200
    names = [c["name"] for c in table["campaign"] + table["command"]]
    assert len(set(names)) == len(names)


@pytest.mark.parametrize("kind, case", _cases())
def test_malformed_input_gives_one_line_and_creates_nothing(world, kind, case):
    project = world["project"]
    if kind == "campaign":
        (project / "case.toml").write_text(campaign_file(world["table"]["base"], case))
        args = ["run", "case.toml", "--out", "new"]
    else:
        args = case["args"]
    before = _tree(project)
    code, err = run_case(world, args, program=case.get("subprocess", False))
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert err.rstrip("\n") == case["message"]
    assert code == case.get("code", 2)
    assert "internal error" not in err
    assert _tree(project) == before
