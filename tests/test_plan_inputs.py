"""The plan-inputs digest (labrunner.campaign.plan_inputs) covers the code that plans, found by
reading the sources, and nothing else: an edit elsewhere in labrunner keeps a stored plan trusted,
an edit of the planning code makes ``resume`` re-plan."""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from test_campaign_support import ROOT

import labrunner
from labrunner.campaign import plan_inputs, spec

#: Campaigns whose planning, together, reaches every rig family and controller table entry in use.
PLANNED = ("quickstart.toml", "valve-gamma-kp.toml", "plate-alpha-omegac.toml", "dcmotor-angle-kp-kd.toml")


def test_the_closure_holds_every_module_that_planning_imports():
    """The independent reference: the labrunner modules a fresh interpreter has loaded after
    loading and planning shipped campaigns of every rig family."""
    code = (
        "import sys, json\n"
        "from labrunner.campaign import spec\n"
        f"for name in {PLANNED!r}:\n"
        "    c = spec.load('campaigns/' + name)\n"
        "    spec.plan(c)\n"
        "print(json.dumps(sorted(m.__file__ for n, m in sys.modules.items()\n"
        "    if n.split('.')[0] == 'labrunner' and getattr(m, '__file__', None))))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    package = Path(labrunner.__file__).resolve().parent
    loaded = {Path(f).resolve().relative_to(package).as_posix() for f in json.loads(out.stdout)}
    files = set(plan_inputs.code_files())
    assert loaded - files == set()
    # and it is narrower than the package: the analysis, logs, results, CLI and runtime are not inputs
    for outside in ("analysis/table.py", "logs/reader.py", "results/campaign.py", "cli/__init__.py"):
        assert outside not in files
    for outside in ("campaign/ledger.py", "campaign/runner.py", "campaign/scheduler.py", "campaign/worker.py"):
        assert outside not in files


def _ast_imports(module: str, whole: bool) -> set[str]:
    """A plain reference for the line scanner: the imports Python's own parser finds."""
    tree = ast.parse(plan_inputs._file(module).read_text())
    package = module if plan_inputs._file(module).name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()

    def visit(nodes):
        for node in nodes:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and not whole:
                continue
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*parts, base] if base else parts)
                found.update(f"{base}.{a.name}" if plan_inputs._file(f"{base}.{a.name}") else base for a in node.names)
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.stmt | ast.excepthandler | ast.match_case):
                    visit([child])

    visit(tree.body)
    if whole:
        found.update(
            n.value.split(":")[0]
            for n in ast.walk(tree)
            if isinstance(n, ast.Constant)
            and isinstance(n.value, str)
            and re.fullmatch(r"labrunner(\.\w+)+(:\w+)?", n.value)
        )
    return {name for name in found if name.split(".")[0] == "labrunner"}


def test_the_line_scanner_finds_what_pythons_parser_finds():
    """Over every module of the package, each way a module may be followed (whole, or a package's
    ``__init__`` only): the scanner finds every import the parser finds (it may find more — a
    ``"labrunner.x"`` in a docstring — which only widens the closure)."""
    package = Path(labrunner.__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package).with_suffix("").parts
        module = ".".join(["labrunner", *(parts[:-1] if parts[-1] == "__init__" else parts)])
        for whole in (True, False):
            text = path.read_text()
            assert plan_inputs._imports(module, text, whole) >= _ast_imports(module, whole), (module, whole)


@pytest.fixture
def package_copy(tmp_path, monkeypatch) -> Path:
    """A copy of labrunner's sources that the digest reads instead of the installed ones."""
    copy = tmp_path / "labrunner"
    shutil.copytree(Path(labrunner.__file__).resolve().parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(plan_inputs, "_PACKAGE", copy)
    plan_inputs.code_files.cache_clear()
    yield copy
    plan_inputs.code_files.cache_clear()


def _edit(path: Path) -> None:
    path.write_text(path.read_text() + "\n# an edit\n")


@pytest.mark.parametrize(
    ("edited", "changes"),
    [
        ("analysis/table.py", False),  # the analysis does not plan
        ("cli/run_cmd.py", False),
        ("campaign/ledger.py", False),
        ("campaign/grid.py", True),  # point ids and grid expansion
        ("campaign/checks.py", True),  # the static checks
        ("rigs/device/plan.py", True),  # imported inside spec.plan
        ("control/mfc.py", True),  # named only in the controller table ("module:function")
        ("rigs/sim/valve.py", True),  # named only in the rig-kind table
    ],
)
def test_an_edit_changes_the_digest_only_where_it_can_change_the_plan(project, package_copy, edited, changes):
    campaign = spec.load(ROOT / "campaigns" / "quickstart.toml")
    stored = plan_inputs.stamp(campaign)
    meta = dict(stored)
    assert plan_inputs.unchanged(campaign, meta)
    _edit(package_copy / edited)
    plan_inputs.code_files.cache_clear()
    assert plan_inputs.unchanged(campaign, meta) is not changes  # hashed again from the stored file list
    assert (plan_inputs.stamp(campaign) != stored) is changes  # and from the closure found afresh


def test_a_new_import_in_a_planning_module_joins_the_closure(package_copy):
    assert "analysis/table.py" not in plan_inputs.code_files()
    grid = package_copy / "campaign" / "grid.py"
    grid.write_text(grid.read_text() + "\n\ndef _later():\n    from labrunner.analysis import table  # noqa\n")
    plan_inputs.code_files.cache_clear()
    assert "analysis/table.py" in plan_inputs.code_files()


def test_imports_under_type_checking_and_lazy_package_exports_are_not_followed(package_copy):
    """``labrunner/__init__.py`` names the results API under TYPE_CHECKING and imports it in its
    ``__getattr__``: neither runs when planning imports a submodule."""
    files = plan_inputs.code_files()
    assert "__init__.py" in files and "results/__init__.py" not in files


def test_the_digest_does_not_depend_on_the_working_directory(tmp_path, monkeypatch):
    """A rig file keeps its path as displayed (relative to the working directory): the digest names it
    absolutely, so that a ``resume`` from another directory trusts the stored plan (the synthetic
    ledgers of bench_scale, whose plan cannot be re-planned, were refused from their own folder)."""
    campaign = ROOT / "campaigns" / "quickstart.toml"
    monkeypatch.chdir(ROOT)
    here = spec.load(campaign)
    assert not Path(here.rig_config.to_dict()["rig"]["source"]).is_absolute()  # what made it differ
    stored = plan_inputs.stamp(here)
    monkeypatch.chdir(tmp_path)
    assert plan_inputs.unchanged(spec.load(campaign), stored)
