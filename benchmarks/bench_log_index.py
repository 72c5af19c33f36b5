"""What the message indexes cost (issue 34): the same runs written in the labrunner-3 layout
(``/run/samples`` without message indexes, which @mcap/core's McapIndexedReader — Foxglove's —
refuses) and in the labrunner-4 layout (every chunk indexed: 16 uncompressed bytes a sample),
file size and write time per run; and what ``labrunner upgrade-logs`` spends per old log
(rewrite alone, and rewrite + read back and compare).

    nice python benchmarks/bench_log_index.py [--motor-runs 200] [--repeat 5] [--dir /dev/shm]

Runs: 5 s motor runs at 200 Hz (8 signals, written as a worker writes a batch: the shared part
once), a 25 s valve run at 4 kHz (6 signals) and a 3 s plate run at 32 kHz (10 signals), the
synthetic signals of ``bench_logs``. Times are CPU seconds (best of ``--repeat`` for the single
runs), so other jobs on the machine matter less.

Last measured 2026-12-04 15:03 UTC (2-core machine shared with other jobs, load average ~18,
/tmp on ext4; two runs, the second's figures)::

    run                          labrunner-3           labrunner-4        cost of the indexes
    motor 1000 samples × 200     82.6 kB  1.06 ms      98.6 kB  1.09 ms   +16.0 kB (+19 %), +0.03 ms
      upgrade-logs per log: rewrite 0.67 ms, with read back and compare 3.80 ms CPU
    valve 25 s at 4 kHz        4743.4 kB 37.76 ms    6343.6 kB 41.12 ms   +1600.2 kB (+34 %), +3.36 ms
      upgrade-logs per log: rewrite 20.70 ms, with read back and compare 65.24 ms CPU
    plate 3 s at 32 kHz        6144.1 kB 52.14 ms    7680.4 kB 48.17 ms   +1536.3 kB (+25 %), -3.96 ms
      upgrade-logs per log: rewrite 22.83 ms, with read back and compare 84.72 ms CPU

The size grows by exactly 16.0 bytes a sample (the index entry; the message index record's own
15 bytes a chunk are lost in the rounding). The write time does not change beyond the noise of
the shared machine (the first run: +0.01, +2.09, +0.93 ms): the entries are numpy arrays the
writer had already built. The synthetic motor runs are noisier than a real campaign's; on the
quickstart campaign's real logs the indexes add the same 16.0 kB to a median completed run of
48.6 kB, +33 % (``bench_log_size.py``).
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_logs import CAMPAIGN_FILE, OUTCOME, RIG, meta, motor_run, plate_run

from labrunner.logs import read_run, write_run
from labrunner.logs.upgrade import rewrite, same_run
from labrunner.logs.writer import LogPrefix

LAYOUTS = ("labrunner-3", "labrunner-4")


def valve_run(seed: int = 0, fs: float = 4000.0, duration: float = 25.0) -> dict[str, np.ndarray]:
    """Flow [l/min] following 1 → 5 → 1 with noise, its reference, error, estimate, current [A]."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(fs * duration)) / fs
    ref = 1 + 4 * np.clip(t / 5, 0, 1) - 4 * np.clip((t - 15) / 5, 0, 1)
    flow = ref + 0.02 * rng.standard_normal(t.size)
    return {
        "q": flow,
        "ref_q": ref,
        "e_q": flow - ref,
        "f_hat_q": 0.1 * rng.standard_normal(t.size),
        "i": 0.5 + 0.1 * ref + 0.01 * rng.standard_normal(t.size),
        "x_spool": 1e-3 * ref,
    }


def cpu(fn) -> float:
    start = time.process_time()
    fn()
    return time.process_time() - start


def prefix(fs: float, names: list[str], layout: str) -> LogPrefix:
    return LogPrefix(
        fs=fs, channels=names, shared={"rig": RIG}, attachments={"campaign.toml": CAMPAIGN_FILE}, log_format=layout
    )


def write_runs(directory: Path, fs: float, runs: list[dict[str, np.ndarray]], layout: str) -> tuple[float, list[Path]]:
    """CPU seconds to write ``runs`` (one prefix for all), and the files."""
    shared = prefix(fs, list(runs[0]), layout)
    paths = [directory / f"{layout}-{i:05d}.mcap" for i in range(len(runs))]

    def write_all() -> None:
        for i, (path, signals) in enumerate(zip(paths, runs)):
            write_run(path, metadata=meta(i), signals=signals, outcome=OUTCOME, prefix=shared, start_time=1.7e9)

    return cpu(write_all), paths


def upgrade_costs(paths: list[Path]) -> tuple[float, float]:
    """CPU seconds a log to rewrite it (into memory), and to rewrite it, read both and compare."""
    rewrite_s = min(cpu(lambda p=p: rewrite(p, io.BytesIO())) for p in paths)
    target = paths[0].with_suffix(".new")

    def full(p: Path) -> None:
        old = read_run(p)
        with open(target, "wb") as fh:
            rewrite(p, fh)
        same_run(old, target)

    return rewrite_s, min(cpu(lambda p=p: full(p)) for p in paths)


def bench(directory: Path, label: str, fs: float, runs: list[dict[str, np.ndarray]], repeat: int) -> None:
    figures = {}
    for layout in LAYOUTS:
        sub = directory / f"{label}-{layout}"
        sub.mkdir()
        if len(runs) > 1:  # a batch: CPU per file over all of them
            seconds, paths = write_runs(sub, fs, runs, layout)
            per_file = seconds / len(runs)
        else:
            per_file = min(write_runs(sub, fs, runs, layout)[0] for _ in range(repeat))
            paths = sorted(sub.iterdir())
        size = float(np.mean([p.stat().st_size for p in paths]))
        figures[layout] = (size, per_file, paths)
    (s3, t3, old), (s4, t4, _) = figures["labrunner-3"], figures["labrunner-4"]
    n = len(next(iter(runs[0].values())))
    print(
        f"{label:<28} {s3 / 1e3:9.1f} kB {1e3 * t3:7.2f} ms   {s4 / 1e3:9.1f} kB {1e3 * t4:7.2f} ms   "
        f"+{(s4 - s3) / 1e3:.1f} kB ({(s4 - s3) / n:.1f} B a sample, +{100 * (s4 / s3 - 1):.0f} %), "
        f"{1e3 * (t4 - t3):+.2f} ms"
    )
    rewrite_s, full_s = upgrade_costs(old[: max(1, min(len(old), repeat))])
    print(
        f"{'':<28} upgrade-logs per log: rewrite {1e3 * rewrite_s:.2f} ms, with read back and compare {1e3 * full_s:.2f} ms CPU"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motor-runs", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--dir", default=None, help="parent directory of the files written")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        print(f"files in {tmp}; size a file, CPU time to write it")
        print(f"{'run':<28} {'labrunner-3':>21}   {'labrunner-4':>21}   cost of the indexes")
        runs = [motor_run(i) for i in range(args.motor_runs)]
        bench(Path(tmp), f"motor 1000 samples × {args.motor_runs}", 200.0, runs, args.repeat)
        bench(Path(tmp), "valve 25 s at 4 kHz", 4000.0, [valve_run()], args.repeat)
        bench(Path(tmp), "plate 3 s at 32 kHz", 32000.0, [plate_run()], args.repeat)


if __name__ == "__main__":
    main()
