"""Figures drawn in forked children: the same result as in this process, and a failed child falls
back to this process."""

import os
import sys

import pytest
from test_analysis_support import make_campaign

from labrunner.analysis.analyse import analyse
from labrunner.analysis.background import Background

forks = pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork on this platform")


@forks
def test_the_function_runs_in_another_process_and_its_result_comes_back(tmp_path):
    def work():
        (tmp_path / "side-effect").write_text(str(os.getpid()))
        return {"pid": os.getpid(), "data": list(range(100_000))}  # more than a pipe's buffer

    job = Background(work)
    result = job.result()
    assert result["pid"] != os.getpid() and result["data"] == list(range(100_000))
    assert (tmp_path / "side-effect").read_text() == str(result["pid"])


@forks
def test_a_failed_child_falls_back_to_this_process():
    parent = os.getpid()

    def work():
        if os.getpid() != parent:
            os._exit(3)  # as if the child had crashed
        return "here"

    assert Background(work).result() == "here"

    def broken():
        raise ValueError("bad data")

    with pytest.raises(ValueError, match="bad data"):  # the error is the one this process would raise
        Background(broken).result()


@forks
def test_close_waits_for_an_unwanted_child():
    job = Background(lambda: sys.exit(0))
    pid = job._pid
    job.close()
    with pytest.raises(ChildProcessError):  # reaped: no zombie left
        os.waitpid(pid, os.WNOHANG)
    job.close()  # once is enough


@forks
def test_figures_drawn_in_children_equal_those_drawn_here(tmp_path):
    """workers=2: the run plots and the second map come from forked children; byte for byte the
    files one process draws, and the same summary."""
    make_campaign(tmp_path)
    here = analyse(tmp_path, tmp_path / "one", workers=1, progress=False)
    child = analyse(tmp_path, tmp_path / "two", workers=2, progress=False)
    assert len(here["run_plots"]) == len(child["run_plots"]) == 3 and len(here["maps"]) == len(child["maps"]) == 2
    for a, b in zip(here["maps"] + here["run_plots"], child["maps"] + child["run_plots"]):
        assert os.path.basename(a) == os.path.basename(b)
        assert open(a, "rb").read() == open(b, "rb").read()
    paths = ("maps", "run_plots", "metrics", "report")
    assert {k: v for k, v in here.items() if k not in paths} == {k: v for k, v in child.items() if k not in paths}
    text = [open(s["report"], encoding="utf-8").read() for s in (here, child)]
    assert text[0].replace(str(tmp_path / "one"), "OUT") == text[1].replace(str(tmp_path / "two"), "OUT")
