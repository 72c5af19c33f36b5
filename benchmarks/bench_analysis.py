"""Benchmark of `labrunner analyse`: 1000+ run logs of a γ–k_p motor campaign (target ≤ 10 s on 2 cores).

Runs a 32 × 32 γ–k_p campaign of first-order MFC on the simulated DC motor once (into a temporary
directory, not timed), then times: the cold analysis (every log read, in parallel), a second
analysis from the cache, and the metrics table alone (every log read again).

    python benchmarks/bench_analysis.py [--workers 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = """
[campaign]
name = "bench-analysis"
description = "γ–k_p sweep for the analysis benchmark"
rig = "dcmotor-sim"
fs = 200.0

[controller]
kind = "mfc1"
output = "velocity"
gamma = 108.55
k_p = 50.0

[differentiator]
alpha = 9
beta = 9
omega_c = 200.0

[reference]
kind = "setpoints"
levels = [0.0, 20.0, 0.0]
transition = 1.0
hold = 1.0

[grid]
"controller.gamma" = { log10 = [0.0, 4.0], num = 32 }
"controller.k_p" = { log10 = [-1.0, 3.0], num = 32 }
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", type=Path, help="campaign directory to reuse/keep (default: a temporary one)")
    args = parser.parse_args()

    from labrunner.analysis import analyse as analyse_mod, table as table_mod
    from labrunner.cli import main as cli

    tmp = Path(tempfile.mkdtemp(prefix="bench-analysis-"))
    directory = args.keep or tmp / "campaign"
    if not (directory / "ledger.sqlite").exists():
        spec_file = ROOT / "campaigns" / ".bench-analysis.toml"
        spec_file.write_text(CAMPAIGN, encoding="utf-8")
        try:
            t = time.perf_counter()
            assert cli(["run", str(spec_file), "--out", str(directory), "--workers", str(args.workers)]) == 0
            print(f"campaign run (not part of the figure): {time.perf_counter() - t:.1f} s")
        finally:
            spec_file.unlink()
    out = tmp / "report"
    logs = len(list((directory / "runs").glob("*.mcap")))

    from labrunner.campaign.ledger import Ledger

    t = time.perf_counter()
    summary = analyse_mod.analyse(directory, out, workers=args.workers)
    cold = time.perf_counter() - t
    t = time.perf_counter()
    again = analyse_mod.analyse(directory, out, workers=args.workers)
    warm = time.perf_counter() - t
    with Ledger.open_readonly(directory) as ledger:
        rows = [dict(r) for r in ledger.rows()]
    t = time.perf_counter()
    table_mod.build_table(rows, directory, workers=args.workers)
    table = time.perf_counter() - t

    print(f"logs: {logs}, workers: {args.workers}")
    print(f"cold analysis (all logs read): {cold:.2f} s  (target <= 10 s)  [{summary['logs_read']} logs read]")
    print(f"  metrics table alone (all logs read): {table:.2f} s ({table / max(logs, 1) * 1e3:.2f} ms per log)")
    print(f"re-analysis from the cache: {warm:.2f} s  [{again['logs_read']} logs read]")
    print(f"maps: {len(summary['maps'])}, run plots: {len(summary['run_plots'])}, agreement: {summary['agreement']['share']}")
    if args.keep is None:
        shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
