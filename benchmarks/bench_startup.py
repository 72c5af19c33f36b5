"""Start-up of the ``labrunner`` command (issue 14); prints figures.

1. ``labrunner --version``, ``--help`` and ``status DIR``: best of ``--repeat`` fresh processes,
   wall time from launch to exit. Target ≤ 0.2 s each.
2. ``labrunner run FILE``: wall time from launch until a worker hands the first batch to the
   engine (``labrunner.engine.run_batch`` entered; a one-point 0.05 s campaign), and the CPU time
   the runner and the worker spent until then (the wall time of an idle machine). Target ≤ 0.5 s.
   The same launch → first batch for a 1000-point motor γ–k_p grid (its plan validates every
   point) and the plate's fig07 campaign (stopped once their first batch starts).
3. What each command imports (``python -X importtime``): total import time and the heaviest
   top-level packages; scipy, matplotlib, pandas and dask must not be among those of
   ``--version``, ``--help`` and ``status``.

Run: ``python benchmarks/bench_startup.py [--repeat 5]``. On a shared machine, read the best
figures: start-up is short enough for other processes' load to dominate single measurements.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from motor_campaign import motor_campaign

HEAVY = ("scipy", "matplotlib", "pandas", "dask", "distributed")
GRID_1000 = (
    '"controller.gamma" = { log10 = [1.0, 3.0], num = 40 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 25 }\n'
)
PLATE = Path(__file__).resolve().parents[1] / "campaigns" / "plate-paper" / "fig07-kp-kd.toml"
CAMPAIGN = motor_campaign("startup", levels="[0.0, 20.0]", hold=0.5, duration=0.1)  # 20 samples ≥ the 14-sample window
# Run in the command's process: when labrunner.engine is loaded (in a worker), report the time
# its run_batch is first entered; nothing else is imported early.
HOOK = """
import importlib.abc, importlib.machinery, sys, time
class _Hook(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != "labrunner.engine":
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        exec_module = spec.loader.exec_module
        def run(module):
            exec_module(module)
            inner = module.run_batch
            def run_batch(*a, **k):
                import os
                with open(f"/proc/{os.getppid()}/stat") as fh:  # the runner's CPU time so far
                    utime, stime = fh.read().rsplit(")", 1)[1].split()[11:13]
                cpu = (int(utime) + int(stime)) / os.sysconf("SC_CLK_TCK") + time.process_time()
                print(f"first batch at {time.time():.6f} {cpu:.3f}", file=sys.stderr, flush=True)
                return inner(*a, **k)
            module.run_batch = run_batch
        spec.loader.exec_module = run
        return spec
sys.meta_path.insert(0, _Hook())
from labrunner.cli import main
sys.exit(main(sys.argv[1:]))
"""


def best_wall(args: list[str], cwd: Path, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(args, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        best = min(best, time.perf_counter() - t0)
    return best


def first_batch(work: Path, path: Path, repeat: int, workers: int = 1) -> tuple[float, float]:
    """Best of ``repeat``: launch → the first run_batch call in a worker, wall time [s] and the CPU
    time the runner and that worker spent until then [s] (what the wall time is on an idle machine).
    The campaign is stopped there (SIGKILL: its workers die with it), as only its start is timed."""
    best, best_cpu = float("inf"), float("inf")
    for i in range(repeat):
        out = work / f"{path.stem}-{i}"
        t0 = time.time()
        args = [sys.executable, "-c", HOOK, "run", str(path), "--out", str(out), "--workers", str(workers)]
        with subprocess.Popen(args, cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True) as proc:
            seen = []
            for line in proc.stderr:  # type: ignore[union-attr]
                if line.startswith("first batch at"):
                    stamp, cpu = map(float, line.split()[-2:])
                    best, best_cpu = min(best, stamp - t0), min(best_cpu, cpu)
                    break
                seen.append(line)
            else:
                raise SystemExit(f"{path.name} never started a batch: {''.join(seen)[-2000:]}")
            proc.kill()
    return best, best_cpu


def imports(args: list[str], cwd: Path) -> tuple[float, list[tuple[str, float]], set[str]]:
    """One command's total import time [s], its top-level packages by cumulative import time, and
    every package it imports at any depth."""
    proc = subprocess.run([sys.executable, "-X", "importtime", *args], cwd=cwd, capture_output=True, text=True)
    per_package: dict[str, float] = {}
    everything: set[str] = set()
    total = 0.0
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or line.count("|") != 2:
            continue
        _, cumulative, name = line.split("|")
        if not cumulative.strip().isdigit():
            continue
        package = name.strip().split(".")[0]
        everything.add(package)
        if not name.startswith("  "):  # a top-level import of this process
            seconds = int(cumulative) * 1e-6
            total += seconds
            per_package[package] = per_package.get(package, 0.0) + seconds
    return total, sorted(per_package.items(), key=lambda kv: -kv[1]), everything


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="fresh processes per figure; the best is reported")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_startup_"))
    try:
        path = work / "startup.toml"
        path.write_text(CAMPAIGN)
        cli = [sys.executable, "-m", "labrunner"]
        subprocess.run([*cli, "run", str(path), "--out", str(work / "done")], cwd=work, check=True, capture_output=True)
        commands = {"--version": ["--version"], "--help": ["--help"], "status": ["status", str(work / "done")]}
        for label, argv in commands.items():
            wall = best_wall([*cli, *argv], work, args.repeat)
            total, top, everything = imports(["-m", "labrunner", *argv], work)
            heavy = sorted(everything & set(HEAVY))
            listing = ", ".join(f"{name} {s * 1e3:.0f} ms" for name, s in top[:4])
            print(
                f"labrunner {label:<10} {wall:5.3f} s (target <= 0.2 s); imports {total:.3f} s: {listing}"
                + (f"; HEAVY: {', '.join(heavy)}" if heavy else "")
            )
        first, cpu = first_batch(work, path, args.repeat)
        print(
            f"labrunner run: first batch in the engine {first:.3f} s after launch, {cpu:.3f} s of CPU time on the way "
            "(target <= 0.5 s)"
        )
        big = work / "motor-1000.toml"
        big.write_text(motor_campaign("motor1000", levels="[0.0, 20.0, 0.0]", hold=1.0, grid=GRID_1000))
        for label, campaign in (("1000-point motor", big), ("plate (fig07, 49 points)", PLATE)):
            wall, _ = first_batch(work, campaign, args.repeat, workers=2)
            print(f"  {label} campaign: first batch {wall:.3f} s after launch")
        total, top, _ = imports(
            ["-m", "labrunner", "run", str(path), "--out", str(work / "imports"), "--workers", "1"], work
        )
        print(
            f"  run's imports (runner and worker) {total:.3f} s: "
            + ", ".join(f"{n} {s * 1e3:.0f} ms" for n, s in top[:6])
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
