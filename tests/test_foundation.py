"""The foundation of issue 2: the package metadata, the `labrunner` entry point, the README's two
set-up-and-go commands and CI running the README's test command verbatim."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import labrunner
from labrunner.cli import COMMANDS, main

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The shell blocks of the README's "Two commands" section."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Two commands", 1)[1].split("\n## ", 1)[0]
    return [block.strip() for block in re.findall(r"```sh\n(.*?)```", section, flags=re.S)]


def test_pyproject_declares_the_package_script_python_and_bounded_dependencies():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert meta["name"] == "labrunner" and meta["requires-python"] == ">=3.11"
    assert meta["scripts"] == {"labrunner": "labrunner.cli:main"}
    for dep in meta["dependencies"] + meta["optional-dependencies"]["test"]:
        assert re.fullmatch(r"[A-Za-z0-9_.\-]+(\[[a-z,]+\])?>=[0-9.]+", dep), dep  # a lower bound each
    tests = {re.split(r"[>\[]", d)[0] for d in meta["optional-dependencies"]["test"]}
    assert {"pytest", "algdiff"} <= tests


def test_top_level_layout_and_ignored_outputs():
    for folder in ("labrunner", "rigs", "campaigns", "tests", "data"):
        assert (ROOT / folder).is_dir(), folder
    ignored = (ROOT / ".gitignore").read_text(encoding="utf-8").split()
    assert "data/*" in ignored and "!data/README.md" in ignored


def test_readme_has_exactly_two_commands_and_ci_runs_the_test_one_verbatim():
    main_job, tests = readme_commands()
    assert "labrunner run campaigns/" in main_job and main_job.startswith("python3 -m venv .venv && ")
    # tests/setup.sh makes the venv, installs the package with its test extra, the system tools the
    # firmware and browser tests drive, and the npm packages; LABRUNNER_CI=1 turns a missing tool into a
    # failure rather than a skip.
    assert tests == (
        "tests/setup.sh && .venv/bin/ruff check . && .venv/bin/ruff format --check . "
        "&& LABRUNNER_CI=1 .venv/bin/python -m pytest"
    )
    setup = (ROOT / "tests" / "setup.sh").read_text(encoding="utf-8")
    assert "python3 -m venv .venv" in setup and '.venv/bin/pip install -q -e ".[test]"' in setup
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert ci[0] == "#!/usr/bin/env bash" and "set -euo pipefail" in ci  # a failing test fails CI
    assert [line for line in ci if line and not line.startswith(("#", "set ", "cd "))] == [tests]
    campaign = main_job.split("labrunner run ", 1)[1].split()[0]
    assert (ROOT / campaign).is_file()


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"labrunner {labrunner.__version__}"
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    out = capsys.readouterr().out
    assert exc.value.code == 0 and all(re.search(rf"^\s+{name}\b", out, flags=re.M) for name in COMMANDS)
    assert main([]) == 2  # no command: the help, and the usage-error exit code


def test_console_script_runs():
    """The installed `labrunner` script (next to the interpreter of the README's venv)."""
    script = Path(sys.executable).with_name("labrunner")
    if not script.exists():
        pytest.skip("labrunner is not installed next to this interpreter")
    proc = subprocess.run([str(script), "--version"], capture_output=True, text=True, check=False)
    assert proc.returncode == 0 and proc.stdout.strip() == f"labrunner {labrunner.__version__}"
