"""Runs per second per core of the run engine, with and without writing each run's MCAP.

    python benchmarks/bench_engine.py [--batch 100] [--repeat 3]

Target (issue 5): motor velocity MFC at 200 Hz, 5 s runs, including MCAP writing, ≥ 200 runs/s
per core in batches of ≥ 100. Two batches of ``campaigns/dcmotor-velocity-gamma-kp.toml``, run in
this one process (best of ``--repeat`` rounds): ``--batch`` points spread over its γ–k_p grid
(some abort early, as in the campaign), and the worst case, its nominal point (γ = b,
k_p = 50 1/s) ``--batch`` times with different seeds, every run completing all 5 s. Runs per
second are counted in CPU time; wall time is printed alongside. The engine reports its ticks to
a live-progress slot as in a campaign's pool worker (:mod:`labrunner.campaign.live`).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from labrunner import engine
from labrunner.campaign import live, spec
from labrunner.logs import write_run
from labrunner.rigs.registry import load_rig

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=100, help="runs per lockstep batch")
    parser.add_argument("--repeat", type=int, default=3, help="rounds; the best is reported")
    args = parser.parse_args()

    campaign = spec.load(ROOT / "campaigns" / "dcmotor-velocity-gamma-kp.toml", root=ROOT)
    points, _ = spec.plan(campaign)
    step = max(len(points) // args.batch, 1)
    spread = [campaign.resolve(p.parameters) for p in points[::step][: args.batch]]
    nominal = [campaign.resolve({})] * args.batch
    print(f"campaign {campaign.name}: {campaign.duration:g} s runs at {campaign.fs:g} Hz, one process")
    measure(campaign, "spread over the grid", spread, args.repeat)
    measure(campaign, "nominal point (worst case)", nominal, args.repeat)


def measure(campaign: spec.Campaign, label: str, configs: list[dict], repeat: int) -> None:
    """Best of ``repeat`` rounds, in wall time and in CPU time (what counts when other processes
    share the cores: "per core" is one process's CPU time)."""
    fs, duration = campaign.fs, float(campaign.duration)
    rig = load_rig(campaign.rig_ref, search=campaign.rig_search)
    live.install(live.LiveTicks(1).array)  # as a pool worker's initializer does
    best = {"engine": [math.inf, math.inf], "total": [math.inf, math.inf]}  # [wall, CPU] seconds
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        results = engine.run_batch(
            configs,
            rig,
            fs=fs,
            duration=duration,
            seeds=list(range(len(configs))),
            rig_safety=campaign.rig_safety,
            progress=live.hook(live.Address(0, 0)),
        )
        w1, c1 = time.perf_counter(), time.process_time()
        with tempfile.TemporaryDirectory() as tmp:
            for i, r in enumerate(results):
                write_run(
                    Path(tmp) / f"{i}.mcap",
                    metadata={"run": {"i": i}},
                    fs=fs,
                    signals=r.signals,
                    outcome=r.outcome.as_dict(),
                    channels=r.channels,
                )
            w2, c2 = time.perf_counter(), time.process_time()
        for key, wall, cpu in (("engine", w1 - w0, c1 - c0), ("total", w2 - w0, c2 - c0)):
            best[key] = [min(best[key][0], wall), min(best[key][1], cpu)]
    n = len(configs)
    samples = sum(r.n_samples for r in results) / n
    statuses = ", ".join(
        f"{s} {sum(r.outcome.status == s for r in results)}" for s in ("completed", "aborted", "no-motion")
    )
    print(f"{label}: B = {n} ({statuses}; {samples:.0f} samples per run on average)")
    for key, title, target in (
        ("engine", "engine only:        ", ""),
        ("total", "engine + MCAP write:", "   target >= 200 runs/s"),
    ):
        wall, cpu = best[key]
        print(
            f"  {title} {n / cpu:5.0f} runs/s per core ({1e3 * cpu / n:.2f} ms/run CPU; wall {1e3 * wall / n:.2f} ms/run){target}"
        )


if __name__ == "__main__":
    main()
