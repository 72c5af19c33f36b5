"""Live progress from inside running batches: the engine's hook, the shared slots, the words and
ETA of the progress line, and a slow twin's campaign whose progress moves before its first batch ends."""

from __future__ import annotations

import contextlib
import io
import math
import multiprocessing
import os
import re
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from test_campaign_support import campaign_text, write

from labrunner import engine
from labrunner.campaign import live, runner
from labrunner.campaign.ledger import Ledger
from labrunner.campaign.progress import Progress, format_counts
from labrunner.campaign.spec import load, plan
from labrunner.rigs.sim.dcmotor import DCMotorTwin

GRID2 = '"controller.k_p" = { values = [20.0, 30.0, 40.0, 50.0] }'


def _configs(project, duration: float, grid: str = GRID2):
    campaign = load(write(project / "campaigns" / "c.toml", campaign_text("c", duration=duration, grid=grid)))
    points, _ = plan(campaign)
    return campaign, [campaign.resolve(p.parameters) for p in points]


@pytest.mark.parametrize("duration", [5.0, 5.005, 0.3])
def test_the_engine_reports_its_ticks_at_most_progress_calls_times(project, duration):
    campaign, configs = _configs(project, duration)
    K = round(duration * campaign.fs)
    calls: list[int] = []
    run = dict(fs=campaign.fs, duration=duration, seeds=[1] * 4, rig_safety=campaign.rig_safety)
    with_hook = engine.run_batch(configs, _rig(campaign), progress=calls.append, **run)
    every = math.ceil(K / engine.PROGRESS_CALLS)
    assert calls == [*range(every, K, every), K]  # every ⌈K/100⌉ ticks, then once at the end
    assert len(calls) <= engine.PROGRESS_CALLS
    plain = engine.run_batch(configs, _rig(campaign), **run)
    for a, b in zip(with_hook, plain):  # the hook changes nothing the runs do
        assert a.outcome == b.outcome and all(
            np.array_equal(a.signals[n], b.signals[n], equal_nan=True) for n in a.signals
        )


def _rig(campaign):
    from labrunner.rigs.registry import load_rig

    return load_rig(campaign.rig_ref, search=campaign.rig_search)


def test_a_batch_that_ends_early_reports_every_tick_once_at_its_end(project):
    """Every run aborts early (a du/dt bound far below what the controller asks): the loop breaks,
    the hook's last call still says all ticks are done, and it was called fewer times."""
    text = campaign_text("c", duration=5.0, grid=GRID2).replace("max_du_dt = 120.0", "max_du_dt = 1e-3")
    campaign = load(write(project / "campaigns" / "early.toml", text))
    configs = [campaign.resolve(p.parameters) for p in plan(campaign)[0]]
    calls: list[int] = []
    results = engine.run_batch(
        configs,
        _rig(campaign),
        fs=campaign.fs,
        duration=5.0,
        seeds=[1] * 4,
        rig_safety=campaign.rig_safety,
        progress=calls.append,
    )
    assert {r.outcome.status for r in results} == {"aborted"}
    ended = max(r.n_samples for r in results)
    assert calls[-1] == 1000 and calls[:-1] == list(range(10, ended, 10))


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_live_slots_are_reserved_freed_and_written_by_pool_workers(method):
    """The runner's pool forks; a spawned pool gets the shared array through its initializer too."""
    context = multiprocessing.get_context(method)
    ticks = live.LiveTicks(3, context)
    a, b, c = ticks.reserve(), ticks.reserve(), ticks.reserve()
    assert {a.slot, b.slot, c.slot} == {0, 1, 2} and ticks.reserve() is None  # full: that batch shows no progress
    assert ticks.ticks(a) == live.QUEUED and ticks.ticks(None) == live.QUEUED
    with ProcessPoolExecutor(2, mp_context=context, initializer=live.install, initargs=(ticks.array,)) as pool:
        pids = set(pool.map(_write_in_worker, [b, c], [1234, 99]))
    assert os.getpid() not in pids  # written by other processes
    assert ticks.ticks(b) == 1234 and ticks.ticks(c) == 99 and ticks.ticks(a) == live.QUEUED
    ticks.release(a)
    again = ticks.reserve()
    assert again.slot == a.slot and again.serial == a.serial + 1
    assert live.hook(again) is None  # not a pool worker: no channel installed here


def _write_in_worker(address: live.Address, value: int) -> int:
    live.hook(address)(value)
    return os.getpid()


def test_a_late_dask_event_of_a_slots_previous_batch_is_dropped():
    ticks = live.LiveTicks(1, topic="t")
    first = ticks.reserve()
    ticks.receive((0.0, [first.slot, first.serial, 500]))
    assert ticks.ticks(first) == 500
    ticks.release(first)
    second = ticks.reserve()
    ticks.receive((0.0, [first.slot, first.serial, 1000]))  # the first batch's last report, after its result
    assert ticks.ticks(second) == live.QUEUED
    ticks.receive((0.0, [second.slot, second.serial, 0]))
    assert ticks.ticks(second) == 0


def test_the_progress_line_counts_whole_runs_and_shows_those_in_flight_apart(monkeypatch):
    from labrunner.campaign import progress

    now = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    out = io.StringIO()
    p = Progress("camp", 320, {"completed": 10, "aborted": 2}, stream=out, bar=False, interval_s=1e9)
    p.started_runs(64)
    assert "; 64 running)" in p.line()  # nothing known yet from a live channel
    p.live(0.0, 0)
    assert "; 0 running, 64 waiting)" in p.line()
    now[0] = 20.0
    p.live(10.0, 32)  # 32 started, 10 run-equivalents done: 0.5 run/s, 320 − 12 − 10 = 298 left
    line = p.line()
    assert line.startswith(
        "camp: 12/320 (10 completed, 0 no-motion, 2 aborted, 0 failed; 32 running, 31 % through, 32 waiting)"
    )
    assert "0.5 runs/s" in line and "ETA 9:56" in line
    p.live(9.5 + 1.0, 32)  # a batch of one run returned: the others' share and its run whole, until counted
    p.update("completed")
    assert p.position == 13 + 9.5 and p.taken == 31 and p.running == 63
    assert p.line().startswith(
        "camp: 13/320 (11 completed, 0 no-motion, 2 aborted, 0 failed; 31 running, 31 % through, 32 waiting)"
    )
    p.returned(32)  # the waiting batches unclaimed (Ctrl-C before they started)
    assert p.running == 31 and p.finished == 13 and "waiting" not in p.line()


def test_the_bar_moves_with_the_runs_in_flight_and_shows_whole_runs():
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Terminal()
    p = Progress("camp", 10, {"completed": 2}, stream=out, interval_s=0.0)
    p.started_runs(4)
    p.live(2.0, 4)
    p.tick()
    bar = out.getvalue().split("\r")[-1]
    assert re.search(r"camp: +40%.*\| 2/10 \[", bar), bar  # 4 of 10 run-equivalents, 2 whole runs
    assert "4 running, 50 % through" in bar
    p.close()


def _slow_step(step):
    def slow(self, u):
        time.sleep(1e-3)  # a slow twin: 1 ms of wall time a tick, no CPU
        return step(self, u)

    return slow


@pytest.mark.parametrize("executor", ["pool", "dask"])
def test_a_slow_twin_campaign_shows_its_runs_in_flight_before_the_first_batch_ends(project, monkeypatch, executor):
    """Two batches of two 10 s runs at 200 Hz, 1 ms a tick (≥ 2 s a batch), one worker (a forked
    pool's, or a Dask worker's thread: reports as Dask events), a line every 0.1 s: lines with
    nothing committed show the share rising and an ETA; the last line's counts are the ledger's."""
    monkeypatch.setattr(DCMotorTwin, "_step", _slow_step(DCMotorTwin._step))  # pool workers fork from here
    path = write(project / "campaigns" / "slow.toml", campaign_text("slow", duration=10.0, grid=GRID2))
    stream = (project / "progress.txt").open("w+")
    with contextlib.ExitStack() as stack:
        url = None
        if executor == "dask":
            from distributed import LocalCluster

            cluster = LocalCluster(
                n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://", dashboard_address=":0"
            )
            url = stack.enter_context(cluster).scheduler_address
        opts = runner.Options(workers=1, executor=url, batch_size=2, stream=stream, progress_interval_s=0.1)
        started = time.monotonic()
        outcome, directory = runner.start(path, project / "data" / "slow", opts)
    assert time.monotonic() - started > 4.0, "the twin was not slow: the test shows nothing"
    stream.seek(0)
    lines = stream.read().splitlines()
    first = [ln for ln in lines if ln.startswith("slow: 0/4 ")]
    shares = [int(m.group(1)) for ln in first if (m := re.search(r"; 2 running, (\d+) % through, 2 waiting", ln))]
    assert len(shares) >= 5 and shares == sorted(shares), lines  # rising while the first batch runs
    assert 0 < shares[-1] <= 100  # the first batch of two is under way, the second waits for the one worker
    assert all("ETA ?" not in ln for ln in first[-3:]), first  # run-equivalents: an ETA before any run ends
    with Ledger.open_readonly(Path(directory)) as ledger:
        counts = format_counts(ledger.by_outcome())
    assert lines[-1].startswith(f"slow: 4/4 ({counts})") and outcome.committed == 4
