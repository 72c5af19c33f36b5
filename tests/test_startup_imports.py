"""What a command imports (issue 14): the CLI's parser, ``--help`` and a worker's writer path
load none of the heavy packages they do not use. Checked in fresh interpreters (sys.modules)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("pandas", "matplotlib", "scipy.optimize", "dask", "distributed")


def _loaded(code: str) -> list[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize(
    "code",
    [
        "from labrunner.cli import build_parser; build_parser()",  # every command's parser (reproduce lists its items)
        "from labrunner.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n    pass",
    ],
)
def test_the_parser_imports_no_heavy_package(code):
    assert _loaded(code) == []


def test_a_worker_writes_logs_without_pandas_or_matplotlib():
    """The pool worker's modules: the engine, the batch executor and the log writer (through
    ``labrunner.logs``, whose reader builds a pandas frame only when asked)."""
    code = (
        "import labrunner.campaign.scheduler, labrunner.campaign.worker, labrunner.engine\n"
        "from labrunner.logs import BatchPrefixes, write_run, read_metadata"
    )
    assert _loaded(code) == []
