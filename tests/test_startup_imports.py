"""What a command imports (issue 14): the CLI's parser, ``--help`` and a worker's writer path
load none of the heavy packages they do not use. Checked in fresh interpreters (sys.modules)."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("pandas", "matplotlib", "scipy.optimize", "dask", "distributed")


def _loaded(code: str, modules: tuple[str, ...] = HEAVY) -> list[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps([m for m in {modules!r} if m in sys.modules]))"
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


def test_import_labrunner_is_light_and_its_results_api_is_lazy():
    """``import labrunner`` loads nothing heavy; the results API's names load pandas when first
    asked for (module ``__getattr__``), and an unknown name is an AttributeError."""
    assert _loaded("import labrunner\nassert labrunner.__version__") == []
    assert _loaded("import labrunner\nlabrunner.open_campaign", ("pandas",)) == ["pandas"]
    listed = "import labrunner\nassert {'open_campaign', 'Catalog', 'open_run'} <= set(dir(labrunner))"
    assert _loaded(listed, ("pandas",)) == []  # listed (tab completion) before any is imported
    code = "import labrunner\ntry:\n    labrunner.nope\nexcept AttributeError as e:\n    print(e)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "module 'labrunner' has no attribute 'nope'"


def test_a_worker_writes_logs_without_pandas_or_matplotlib():
    """The pool worker's modules: the engine, the batch executor and the log writer (through
    ``labrunner.logs``, whose reader builds a pandas frame only when asked)."""
    code = (
        "import labrunner.campaign.scheduler, labrunner.campaign.worker, labrunner.engine\n"
        "from labrunner.logs import BatchPrefixes, write_run, read_metadata"
    )
    assert _loaded(code) == []


_BLAS_THREADS = """
import ctypes, glob, os, sys
from labrunner.cli import main
main(["run", "no-such-campaign.toml"])  # exits 2 after the campaign commands' set-up
import numpy
libs = glob.glob(os.path.join(os.path.dirname(numpy.__file__), os.pardir, "numpy.libs", "libscipy_openblas64_*.so"))
print(ctypes.CDLL(libs[0]).scipy_openblas_get_num_threads64_() if libs else "no-openblas")
"""


@pytest.mark.parametrize("user", [None, "2"])
def test_a_campaign_process_runs_blas_on_one_thread_unless_the_user_says(user):
    """``run``/``resume`` processes (and the workers they fork) use one OpenBLAS thread: one
    process per core already fills the cores; a user's OPENBLAS_NUM_THREADS is kept."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if user is not None:
        env["OPENBLAS_NUM_THREADS"] = user
    out = subprocess.run([sys.executable, "-c", _BLAS_THREADS], capture_output=True, text=True, env=env)
    threads = out.stdout.strip().splitlines()[-1]
    if threads == "no-openblas":
        pytest.skip("numpy is not built with scipy-openblas here")
    assert int(threads) == int(user or 1)


@pytest.mark.parametrize(("argv", "frozen"), [("None", True), ("['status', '/nonexistent']", False)])
def test_only_the_program_freezes_its_objects_for_a_quick_exit(argv, frozen):
    """``labrunner`` itself ends with its objects frozen (teardown skips the collections that walk
    them); ``main(argv)`` called from Python, as the tests do, leaves the caller's collector alone."""
    code = (
        "import gc, sys\nfrom labrunner.cli import main\nsys.argv = ['labrunner', 'status', '/nonexistent']\n"
        f"code = main({argv})\nprint(code, gc.get_freeze_count() > 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["2", str(frozen)]


def test_the_stability_bounds_and_the_valve_twin_need_no_scipy_optimize():
    """``analyse`` evaluates closed-form bounds and a valve campaign finds its operating point with
    :func:`labrunner.brent.brent_root`; scipy.optimize (~0.2 s) is loaded only by numerical scans."""
    code = (
        "import labrunner.stability as s, labrunner.rigs.sim.valve\n"
        "s.bounds('mfc1-motor', gamma=1.0, delay=0.01, a=2.0, b=50.0)\n"
        "s.bounds('mfc2-second-order', gamma=1.0, delay=0.01, a0=4.0, a1=1.0, b=50.0, k_d=0.5)"
    )
    assert _loaded(code) == []


def test_a_plate_campaign_designs_its_filters_without_scipy_signal():
    """The plate controllers' notch, low-pass and Tustin designs are numpy (checked against
    scipy.signal in tests/test_plate_filters.py); importing scipy.signal took ~0.4 s of start-up."""
    assert _loaded("import labrunner.control.plate, labrunner.control.plate_mbc", ("scipy.signal",)) == []


def test_validating_a_campaign_needs_no_scipy_special():
    """The plan builds every point's controller and safety monitor to check it, and each distinct
    differentiator's weights (a window whose normalisation vanishes is refused there): an N = 0
    kernel is evaluated without scipy.special (~0.2 s), so the runner imports none."""
    quickstart = Path(__file__).resolve().parents[1] / "campaigns" / "quickstart.toml"
    code = f"from labrunner.campaign import spec\nspec.plan(spec.load({str(quickstart)!r}))"
    assert _loaded(code, ("scipy.special",)) == []


def test_analyse_forks_its_drawing_child_before_pandas_and_matplotlib():
    """``labrunner.analysis.analyse`` imports neither (its function forks the drawing child
    first); that child's preparation loads matplotlib and the log reader but no pandas."""
    assert _loaded("import labrunner.analysis.analyse") == []
    assert _loaded("from labrunner.analysis import drawing\ndrawing.prepare()") == ["matplotlib"]


def test_a_process_of_many_analyses_loads_their_drawing_once():
    """``reproduce`` analyses ~30 campaigns: ``prepare_drawing`` loads matplotlib in it once, for each
    analysis's drawing child to be forked with instead of importing it again; with one worker (the
    analyses draw in this process, when they need to) it loads nothing."""
    code = "from labrunner.analysis.analyse import prepare_drawing\nprepare_drawing({})"
    assert _loaded(code.format(2)) == ["matplotlib"]
    assert _loaded(code.format(1)) == []


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork: the analysis draws its figures itself")
def test_with_two_workers_the_analysis_never_loads_matplotlib_and_its_drawing_child_no_pandas(tmp_path, monkeypatch):
    """The drawing child gets the maps as plain data (numpy arrays, no table): it draws them
    without pandas, and the analysis, which only computes them, never loads matplotlib (~0.2 s).
    With one worker the analysis draws everything itself, so it loads both."""
    from test_analysis_support import make_campaign

    from labrunner.analysis import figures
    from labrunner.analysis.analyse import analyse

    make_campaign(tmp_path / "c")
    for workers, expected in ((2, ["pandas"]), (1, ["pandas", "matplotlib"])):
        code = (
            "from labrunner.analysis.analyse import analyse\n"
            f"s = analyse({str(tmp_path / 'c')!r}, {str(tmp_path / f'out{workers}')!r}, workers={workers}, progress=False)\n"
            "assert len(s['maps']) == 2 and len(s['run_plots']) == 3, s"
        )
        assert _loaded(code) == expected
    jobs = []
    monkeypatch.setattr(figures, "map_jobs", lambda *a, _f=figures.map_jobs: jobs.extend(_f(*a)) or jobs)
    analyse(tmp_path / "c", tmp_path / "here", workers=1, progress=False)
    (tmp_path / "jobs.pkl").write_bytes(pickle.dumps(jobs))
    drawn = {job.path: job.path.read_bytes() for job in jobs}
    for path in drawn:
        path.unlink()
    code = (
        "import pickle\nfrom labrunner.analysis import drawing\n"
        f"drawing.draw([], pickle.loads(open({str(tmp_path / 'jobs.pkl')!r}, 'rb').read()))"
    )
    assert _loaded(code) == ["matplotlib"]
    assert len(drawn) == 2 and {path: path.read_bytes() for path in drawn} == drawn


def test_the_light_commands_load_no_numpy(project):
    """``--version``, ``--help`` and ``status`` (a grid's, a real rig's with its law check) only
    read text and SQLite: numpy (~0.1–0.3 s, through ``labrunner.rigs``' Rig interface) stays out
    (issue 36: ``status`` had become ~6.5× a bare Python start)."""
    from test_campaign_support import MOTOR_RIG, campaign_text, write

    from labrunner.cli import main
    from labrunner.rigs.registry import register_rig

    register_rig("inprocess-motor", "test_campaign_support:InProcessMotor")  # a real rig: status checks its laws
    write(project / "rigs" / "bench.toml", MOTOR_RIG.replace('kind = "dcmotor"', 'kind = "inprocess-motor"'))
    for name, rig in (("twin", "rigs/motor.toml"), ("real", "rigs/bench.toml")):
        assert main(["run", str(write(project / f"{name}.toml", campaign_text(name=name, rig=rig, duration=0.5)))]) == 0
    for argv in (["--version"], ["--help"], ["status", "data/twin"], ["status", "data/real", "--json"]):
        code = f"import os\nos.chdir({str(project)!r})\nfrom labrunner.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass"
        assert _loaded(code, ("numpy",)) == [], argv
