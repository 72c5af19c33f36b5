"""Figures drawn in forked children: the same result as in this process, and a failed child falls
back to this process."""

import os
import sys

import pytest
from test_analysis_support import make_campaign

from labrunner.analysis.analyse import BACKGROUND_PLOTS, analyse
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
    """workers=2: the figures come from the drawing child and the child it forks; byte for byte the
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


@forks
def test_many_run_plots_are_drawn_here_while_the_child_draws_the_maps(tmp_path):
    """More run plots than the drawing child takes (--plot all): this process draws them, with
    progress, while the child draws the maps; the same files as one process draws."""
    # 3 × 3 points: 9 run plots, still more than BACKGROUND_PLOTS (8, asserted below), and a 2-D map;
    # the usual 4 × 4 drew 16 run plots twice for the same path
    make_campaign(tmp_path, gammas=(1.0, 10.0, 100.0), k_ps=(0.1, 1.0, 10.0))
    here = analyse(tmp_path, tmp_path / "one", workers=1, plot=["all"], progress=False)
    child = analyse(tmp_path, tmp_path / "two", workers=2, plot=["all"], progress=False)
    assert len(child["run_plots"]) == len(here["run_plots"]) > BACKGROUND_PLOTS and len(child["maps"]) == 2
    for a, b in zip(here["maps"] + here["run_plots"], child["maps"] + child["run_plots"]):
        assert os.path.basename(a) == os.path.basename(b)
        assert open(a, "rb").read() == open(b, "rb").read()


@forks
def test_with_nothing_to_draw_the_drawing_child_is_stopped_not_waited_for(tmp_path, monkeypatch):
    """One point (no map) analysed again, its run plot kept: the child is given nothing (it would
    be waited for while it loads matplotlib) and the plot is still in the summary."""
    make_campaign(tmp_path, gammas=(10.0,), k_ps=(1.0,))
    started = []
    start = Background.start
    monkeypatch.setattr(Background, "start", lambda self, fn: started.append(fn) or start(self, fn))
    first = analyse(tmp_path, workers=2, progress=False)
    assert not first["maps"] and len(first["run_plots"]) == 1 and len(started) == 1
    again = analyse(tmp_path, workers=2, progress=False)
    assert again["run_plots"] == first["run_plots"] and len(started) == 1


def test_plots_to_draw_are_those_not_kept(tmp_path):
    """A run plot newer than its log is kept (not drawn, no child forked for it); a missing or
    older one is drawn; a point without a log has nothing to draw; each point once, in order."""
    from labrunner.analysis.run_plots import items, plot_path, to_draw

    (tmp_path / "runs").mkdir()
    for name in ("a", "b", "c"):
        (tmp_path / "runs" / f"{name}.mcap").write_bytes(b"log")
    out = tmp_path / "report"
    logs = {"a": "runs/a.mcap", "b": "runs/b.mcap", "c": "runs/c.mcap", "d": None}
    for name, offset in (("a", 10), ("b", -10)):  # a's plot newer than its log, b's older
        png = plot_path(out, name)
        png.parent.mkdir(parents=True, exist_ok=True)
        png.write_bytes(b"png")
        log_ns = (tmp_path / "runs" / f"{name}.mcap").stat().st_mtime_ns
        os.utime(png, ns=(log_ns + offset * 10**9, log_ns + offset * 10**9))
    plots = items(logs, ["a", "b", "c", "d", "b"], tmp_path, out)
    assert [p[0] for p in plots] == ["a", "b", "c"]
    assert plots[1] == ("b", tmp_path / "runs" / "b.mcap", out / "plots" / "b.png")
    assert to_draw(plots) == ["b", "c"]


@forks
def test_a_failed_fork_runs_the_function_here(monkeypatch):
    def no_fork():
        raise OSError("Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", no_fork)
    job = Background(lambda: os.getpid())
    assert job.result() == os.getpid()
    job.close()


def _prepared() -> list[str]:
    """In an ahead child: what its ``prepare`` left behind, and where it runs."""
    return [os.environ.get("PREPARED", ""), str(os.getpid())]


@forks
def test_an_ahead_child_prepares_first_and_runs_the_function_sent_to_it_later():
    job = Background.ahead(lambda: os.environ.__setitem__("PREPARED", "yes"))
    job.start(_prepared)
    prepared, pid = job.result()
    assert prepared == "yes" and int(pid) != os.getpid() and "PREPARED" not in os.environ


@forks
def test_an_ahead_child_that_fails_to_prepare_or_gets_nothing_to_do():
    job = Background.ahead(lambda: os._exit(3))  # as if its imports had crashed the child
    job.start(_prepared)
    assert job.result() == ["", str(os.getpid())]  # run here instead
    idle = Background.ahead(lambda: None)
    pid = idle._pid
    idle.close()  # no task: the child is stopped (it was only preparing) and reaped
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)


@forks
def test_without_fork_an_ahead_function_runs_here(monkeypatch):
    def no_fork():
        raise OSError("Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", no_fork)
    job = Background.ahead(lambda: None)
    job.start(_prepared)
    assert job.result() == ["", str(os.getpid())]
    job.close()
