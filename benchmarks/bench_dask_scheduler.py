"""Dask scheduler memory over a campaign (issue 26): does the scheduler's RSS stay flat as runs go by?

Starts a Dask scheduler and two single-thread workers as separate processes (as a cluster sharing
the file system would be), runs a motor γ–k_p campaign of ``--points`` 1 s runs through
``labrunner run --executor tcp://…``, samples the scheduler's RSS every 0.5 s, and prints it
after the first tenth of the runs and at the end, and the growth per run between the two.

    nice -n 10 python benchmarks/bench_dask_scheduler.py [--points 40000] [--work DIR]

Measured 2026-12-03 (2-core machine, niced, load 8–13 from other jobs): in a 10^6-point campaign
of 5 s runs, the scheduler grew by ~2.5 kB a run (the first session's scheduler 0.59 GB after
~210 000 runs; the resumed session's, a fresh scheduler, 0.9 GB after ~342 000 and 1.9 GB after
its 751 028) while every batch's points reached it as ~10^4 small Python objects it unpickled.
Packed as one blob a batch (``executors.PackedExecutor``)::

    points    before (objects)                 after (one blob a batch)
    19,881    95 -> 111 MB, 1069 bytes a run    65 -> 69 MB, 232 bytes a run
    99,856                                      69 -> 93 MB, 290 bytes a run

(RSS after the first tenth of the runs -> at the end). The rest still grows: ~0.3 GB over 10^6
runs, not traced further (the scheduler's own per-task records or its allocator's fragments).
"""

from __future__ import annotations

import argparse
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_campaign import campaign  # noqa: E402

BIN = Path(sys.executable).parent


def _rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _runs_done(err: Path) -> int:
    """Runs finished so far, from the runner's last progress line."""
    found = re.findall(r"(\d+)/\d+ \(", err.read_text(errors="replace")[-2000:])
    return int(found[-1]) if found else 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=40_000, help="campaign size (a square grid; default 40000)")
    parser.add_argument("--work", type=Path, default=None, help="folder for the campaign (deleted after)")
    args = parser.parse_args()
    side = round(args.points**0.5)
    work = Path(tempfile.mkdtemp(prefix="dasksched-", dir=args.work))
    port = _free_port()
    url = f"tcp://127.0.0.1:{port}"
    procs: list[subprocess.Popen] = []
    try:
        scheduler = subprocess.Popen(
            [BIN / "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        procs.append(scheduler)
        time.sleep(3)
        procs.append(
            subprocess.Popen(
                [BIN / "dask", "worker", url, "--nworkers", "2", "--nthreads", "1", "--no-dashboard"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        time.sleep(5)
        text = campaign("dasksched", side, side).replace("duration = 5.0", "duration = 1.0")
        (work / "dasksched.toml").write_text(text)
        err = work / "run.err"
        samples: list[tuple[int, int]] = []  # (runs done, scheduler RSS kB)
        with open(err, "w") as fh:
            run = subprocess.Popen(
                [sys.executable, "-m", "labrunner", "run", "dasksched.toml", "--out", "out", "--executor", url],
                cwd=work,
                stdout=subprocess.DEVNULL,
                stderr=fh,
            )
            stop = threading.Event()

            def sample() -> None:
                while not stop.wait(0.5):
                    samples.append((_runs_done(err), _rss_kb(scheduler.pid)))

            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            t0 = time.perf_counter()
            code = run.wait()
            stop.set()
            sampler.join()
            samples.append((_runs_done(err), _rss_kb(scheduler.pid)))
        if code != 0:
            raise SystemExit(f"labrunner run failed ({code}): {err.read_text()[-500:]}")
        n = side * side
        tenth = next((s for s in samples if s[0] >= n // 10), samples[0])
        end = samples[-1]
        growth = (end[1] - tenth[1]) * 1024 / max(end[0] - tenth[0], 1)
        print(
            f"{n} runs in {time.perf_counter() - t0:.0f} s; scheduler RSS {tenth[1] / 1024:.0f} MB after "
            f"{tenth[0]} runs, {end[1] / 1024:.0f} MB after {end[0]} (peak {max(r for _, r in samples) / 1024:.0f} MB): "
            f"{growth:.0f} bytes a run"
        )
    finally:
        for proc in reversed(procs):
            with_signal = proc.poll() is None
            if with_signal:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
