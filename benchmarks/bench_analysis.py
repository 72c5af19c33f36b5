"""Benchmark of `labrunner analyse` on γ–k_p motor campaigns of 1000 and 10 000 points (target:
≤ 1 ms per run plus ≤ 2 s fixed, from the ledger: logs are read only for the runs it plots).

Runs each campaign of first-order MFC on the simulated DC motor once (into ``--keep DIR`` or a
temporary directory, not timed), then times ``labrunner analyse`` as a user runs it — a fresh
process, imports included — cold (no report yet) and again (its run plots kept), and the metrics
table alone in-process; then fits time = fixed + per-run · N over the two sizes. ``--recompute``
adds an analysis that reads every log again. CPU times are the process's own (the machine may
be shared); wall times are printed too.

    python benchmarks/bench_analysis.py [--sizes 1000 10000] [--workers 2] [--keep DIR] [--recompute]

Last measured (2-core machine shared with other sessions, load average 2.3; CPU includes the
children that draw the run plots and half the maps): 1024 runs 2.36 s CPU (2.31 s wall), 10 000
runs 3.61 s CPU (2.68 s wall); fit 0.14 ms per run + 2.21 s fixed (was 0.49 ms + 3.2 s). The fixed
part is pandas, matplotlib and pyarrow's imports (~0.8 s), scipy for the stability bounds and the
differentiator's δ_t (~0.3 s), the fonts (~0.1 s) and matplotlib's drawing of five figures
(~0.95 s, ticks and text). With one worker (``--workers 1``) the same CPU, ~0.4 s more wall.
Quiet machine (load 0.3), 1000 runs, fresh process: 1.47–1.50 s wall / 2.05–2.12 s CPU, against
2.09–2.22 s / 2.27–2.35 s before these changes (interleaved runs of both).
"""

from __future__ import annotations

import argparse
import math
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from motor_campaign import motor_campaign

ROOT = Path(__file__).resolve().parents[1]


def campaign_text(n: int, side: int) -> str:
    """The γ–k_p sweep of ``side`` × ``side`` points (about ``n``) on log axes."""
    grid = (
        f'"controller.gamma" = {{ log10 = [0.0, 4.0], num = {side} }}\n'
        f'"controller.k_p" = {{ log10 = [-1.0, 3.0], num = {side} }}\n'
    )
    return motor_campaign(
        f"bench-analysis-{n}",
        description="γ–k_p sweep for the analysis benchmark",
        levels="[0.0, 20.0, 0.0]",
        hold=1.0,
        grid=grid,
    )


def campaign(n: int, parent: Path, workers: int) -> Path:
    """The campaign directory of about ``n`` points (a square grid), run once if not there yet."""
    side = round(math.sqrt(n))
    directory = parent / f"campaign-{side * side}"
    if not (directory / "ledger.sqlite").exists():
        spec_file = ROOT / "campaigns" / f".bench-analysis-{side}.toml"
        spec_file.write_text(campaign_text(side * side, side), encoding="utf-8")
        try:
            t = time.perf_counter()
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "labrunner",
                    "run",
                    str(spec_file),
                    "--out",
                    str(directory),
                    "--workers",
                    str(workers),
                ],
                check=True,
                stderr=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
            )
            print(f"  campaign of {side * side} points run (not part of the figures): {time.perf_counter() - t:.1f} s")
        finally:
            spec_file.unlink()
    return directory


def cli_analyse(directory: Path, out: Path, workers: int, *extra: str) -> tuple[float, float]:
    """(wall, CPU) seconds of ``labrunner analyse`` in a fresh process (its children included)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "labrunner",
            "analyse",
            str(directory),
            "--out",
            str(out),
            "--workers",
            str(workers),
            *extra,
        ],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep", type=Path, help="folder for the campaign directories, reused by later runs")
    parser.add_argument("--recompute", action="store_true", help="also time an analysis that reads every log")
    args = parser.parse_args()

    from labrunner.analysis import table as table_mod
    from labrunner.analysis.table_rows import in_chunks
    from labrunner.campaign.ledger import Ledger

    tmp = Path(tempfile.mkdtemp(prefix="bench-analysis-"))
    parent = args.keep or tmp
    parent.mkdir(parents=True, exist_ok=True)
    cold = {}
    print(f"labrunner analyse, {args.workers} workers (CPU: the process's own; the machine may be shared)")
    for n in args.sizes:
        directory = campaign(n, parent, args.workers)
        points = len(list((directory / "runs").glob("*.mcap")))
        out = tmp / f"report-{points}"
        wall, cpu = cli_analyse(directory, out, args.workers)
        cold[points] = cpu
        again_wall, again_cpu = cli_analyse(directory, out, args.workers)
        with Ledger.open_readonly(directory) as ledger:
            rows = [dict(r) for r in ledger.rows()]
        t, c = time.perf_counter(), time.process_time()
        built = table_mod.build_table(in_chunks(rows), directory, workers=args.workers)
        table_wall, table_cpu = time.perf_counter() - t, time.process_time() - c
        print(f"{points} runs:")
        print(f"  analyse, fresh process:         {cpu:6.2f} s CPU ({wall:6.2f} s wall)")
        print(f"  again (run plots kept):         {again_cpu:6.2f} s CPU ({again_wall:6.2f} s wall)")
        print(
            f"  metrics table alone, in-process: {table_cpu * 1e3 / points:5.3f} ms CPU per run"
            f" ({table_wall:.2f} s wall, {built.n_read} logs read)"
        )
        if args.recompute:
            wall, cpu = cli_analyse(directory, tmp / f"recompute-{points}", args.workers, "--recompute")
            print(
                f"  --recompute (every log read):   {cpu:6.2f} s CPU ({wall:6.2f} s wall), parent process and workers"
            )
    if len(cold) >= 2:
        (n0, c0), (n1, c1) = sorted(cold.items())[0], sorted(cold.items())[-1]
        per_run = (c1 - c0) / (n1 - n0)
        print(
            f"fit over {n0} and {n1} runs: {per_run * 1e3:.3f} ms per run + {c0 - per_run * n0:.2f} s fixed "
            "(targets: 1 ms per run, 2 s fixed)"
        )
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
