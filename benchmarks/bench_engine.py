"""Runs per second per core of the run engine, with and without writing each run's MCAP.

    python benchmarks/bench_engine.py [--batch 100] [--repeat 3]

Target (issue 5): motor velocity MFC at 200 Hz, 5 s runs, including MCAP writing, ≥ 200 runs/s
per core in batches of ≥ 100. Two batches of ``campaigns/dcmotor-velocity-gamma-kp.toml``, run in
this one process (best of ``--repeat`` rounds): ``--batch`` points spread over its γ–k_p grid
(some abort early, as in the campaign), and the worst case, its nominal point (γ = b,
k_p = 50 1/s) ``--batch`` times with different seeds, every run completing all 5 s.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from labrunner import engine
from labrunner.campaign import spec
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
    fs, duration = campaign.fs, float(campaign.duration)
    rig = load_rig(campaign.rig_ref, search=campaign.rig_search)
    best_engine = best_total = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        results = engine.run_batch(configs, rig, fs=fs, duration=duration, seeds=list(range(len(configs))),
                                   rig_safety=campaign.rig_safety)
        t1 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            for i, r in enumerate(results):
                write_run(Path(tmp) / f"{i}.mcap", metadata={"run": {"i": i}}, fs=fs, signals=r.signals,
                          outcome=r.outcome.as_dict(), channels=r.channels)
        t2 = time.perf_counter()
        best_engine, best_total = min(best_engine, t1 - t0), min(best_total, t2 - t0)
    n = len(configs)
    samples = sum(r.n_samples for r in results) / n
    statuses = ", ".join(f"{s} {sum(r.outcome.status == s for r in results)}" for s in ("completed", "aborted", "no-motion"))
    print(f"{label}: B = {n} ({statuses}; {samples:.0f} samples per run on average)")
    print(f"  engine only:          {n / best_engine:7.0f} runs/s per core ({1e3 * best_engine / n:.2f} ms/run)")
    print(f"  engine + MCAP write:  {n / best_total:7.0f} runs/s per core ({1e3 * best_total / n:.2f} ms/run)"
          f"   target >= 200 runs/s")

if __name__ == "__main__":
    main()
