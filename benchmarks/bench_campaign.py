"""Campaign orchestration benchmarks (issue 6, "Performance"); prints figures.

1. Per-run orchestration overhead: ledger commit (one transaction per run), publishing a log
   (fsync, rename, directory fsync; measured inside the workers of a real campaign) and scheduling
   (claim, resolve, submit, collect; measured with a no-op batch function). Target: median ≤ 5 ms.
2. A 1000-point motor campaign end to end (`labrunner run`, 2 workers). Target: ≤ 60 s on 2 cores.
3. Peak memory of a 10 000-point campaign (runner + workers, sampled from /proc), and the runner's
   memory at 10 % and 90 % of the runs: it must not grow with the number of runs. Target ≤ 1 GB.

Run: ``python benchmarks/bench_campaign.py [--skip-10k]``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from labrunner.campaign import spec
from labrunner.campaign.ledger import Ledger, RunRecord
from labrunner.campaign.scheduler import InProcessExecutor, Scheduler
from labrunner.campaign.worker import BatchResult, BatchTask

ROOT = Path(__file__).resolve().parents[1]
QUICKSTART = (ROOT / "campaigns" / "quickstart.toml").read_text()


def campaign(name: str, n_gamma: int, n_kp: int) -> str:
    text = QUICKSTART.replace('name = "quickstart"', f'name = "{name}"')
    text = text.replace("log10 = [1.0, 3.0], num = 10", f"log10 = [1.0, 3.0], num = {n_gamma}")
    return text.replace("log10 = [-1.0, 3.0], num = 10", f"log10 = [-1.0, 3.0], num = {n_kp}")


def _noop_batch(task: BatchTask) -> BatchResult:
    now = time.time()
    return BatchResult([
        RunRecord(r.point_id, "completed", {"status": "completed"}, {"rms_error": 0.1, "input_energy": 1.0,
                  "max_abs_input": 1.0}, f"runs/{r.point_id}.mcap", "h", 0, now)
        for r in task.runs
    ])


def bench_commit_and_scheduling(work: Path) -> tuple[float, float]:
    """Median commit time per run [s]; scheduling + commit per run [s] with a no-op batch."""
    path = work / "sched.toml"
    path.write_text(campaign("sched", 40, 25))
    c = spec.load(path)
    points, _ = spec.plan(c)
    d = work / "sched"
    d.mkdir()
    ledger = Ledger.create(d, meta={"campaign": c.name}, points=((p.seq, p.id, p.parameters, p.batch_key) for p in points))
    ids = [p.id for p in points[:500]]
    ledger.claim(ids)
    times = []
    for pid in ids:
        t0 = time.perf_counter()
        ledger.commit(RunRecord(pid, "completed", {"status": "completed"}, {"rms_error": 0.1}, f"runs/{pid}.mcap", "h", 0, time.time()))
        times.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    out = Scheduler(c, ledger, executor=InProcessExecutor(), slots=2, batch_size=25, batch_fn=_noop_batch).run()
    per_run = (time.perf_counter() - t0) / out.committed
    ledger.close()
    return statistics.median(times), per_run


def rss_tree_kb(pid: int) -> tuple[int, int]:
    """(RSS of ``pid``, RSS of pid + all its descendants) in kB, from /proc."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
                children.setdefault(ppid, []).append(int(entry))
            except (OSError, ValueError, IndexError):
                continue

    def rss(p: int) -> int:
        try:
            with open(f"/proc/{p}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        return int(line.split()[1])
        except OSError:
            pass
        return 0

    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        total += rss(p)
        stack += children.get(p, [])
    return rss(pid), total


def run_campaign(work: Path, name: str, n_gamma: int, n_kp: int, sample_rss: bool = False) -> dict:
    path = work / f"{name}.toml"
    path.write_text(campaign(name, n_gamma, n_kp))
    out = work / name
    n = n_gamma * n_kp
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "labrunner", "run", str(path), "--out", str(out), "--workers", "2"],
        cwd=work, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    peak_parent = peak_total = 0
    at: dict[int, int] = {}
    while proc.poll() is None:
        if sample_rss:
            parent, total = rss_tree_kb(proc.pid)
            peak_parent, peak_total = max(peak_parent, parent), max(peak_total, total)
            db = out / "ledger.sqlite"
            if db.exists():
                try:
                    con = sqlite3.connect(f"{db.as_uri()}?mode=ro", uri=True, timeout=1)
                    done = con.execute("SELECT COUNT(*) FROM points WHERE finished_at IS NOT NULL").fetchone()[0]
                    con.close()
                    for pct in (10, 50, 90):
                        if done >= n * pct / 100 and pct not in at:
                            at[pct] = parent
                except sqlite3.Error:
                    pass
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    _, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"campaign {name} failed: {err[-2000:]}")
    con = sqlite3.connect(out / "ledger.sqlite")
    rows = con.execute("SELECT publish_s, write_s, engine_s, state FROM points").fetchall()
    con.close()
    return {
        "wall_s": wall, "n": len(rows), "publish_s": statistics.median(r[0] for r in rows),
        "write_s": statistics.median(r[1] for r in rows), "engine_s": statistics.median(r[2] for r in rows),
        "states": {s: sum(r[3] == s for r in rows) for s in ("done", "aborted", "failed")},
        "peak_parent_kb": peak_parent, "peak_total_kb": peak_total, "parent_at": at,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-10k", action="store_true", help="skip the 10 000-point memory benchmark")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_campaign_"))
    try:
        commit_s, sched_s = bench_commit_and_scheduling(work)
        r1k = run_campaign(work, "bench1k", 40, 25)
        publish_s = r1k["publish_s"]
        print("per-run orchestration overhead (medians):")
        print(f"  ledger commit            {commit_s * 1e3:7.3f} ms")
        print(f"  publish (fsync+rename)   {publish_s * 1e3:7.3f} ms   (log writing itself: {r1k['write_s'] * 1e3:.1f} ms)")
        print(f"  scheduling + commit      {sched_s * 1e3:7.3f} ms   (claim, resolve, submit, collect)")
        print(f"  total                    {(sched_s + publish_s) * 1e3:7.3f} ms   (target <= 5 ms)")
        print(f"1000-point motor campaign end to end: {r1k['wall_s']:.1f} s on 2 workers (target <= 60 s); "
              f"{r1k['states']}; engine {r1k['engine_s'] * 1e3:.1f} ms/run")
        if not args.skip_10k:
            r10k = run_campaign(work, "bench10k", 100, 100, sample_rss=True)
            at = r10k["parent_at"]
            print(f"10 000-point campaign: {r10k['wall_s']:.1f} s; peak RSS runner {r10k['peak_parent_kb'] / 1024:.0f} MB, "
                  f"runner + workers {r10k['peak_total_kb'] / 1024:.0f} MB (target <= 1024 MB)")
            print("  runner RSS at 10 % / 50 % / 90 % of the runs: "
                  + " / ".join(f"{at.get(p, 0) / 1024:.0f} MB" for p in (10, 50, 90)))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
