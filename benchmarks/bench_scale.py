"""Campaign scale (issue 26): run, status, resume, analyse, disk and memory of a motor γ–k_p
campaign (the quickstart's 5 s runs at 200 Hz) at 10^3, 10^4, 10^5 (and, with --max 1000000,
10^6) points, each in fresh processes as a user runs them: ``labrunner run --workers 2``,
``labrunner status`` and a ``labrunner resume`` of the finished campaign (three of each, the
median; ``--repeat``), ``labrunner analyse --workers 2``; the runner's peak RSS and its RSS at 10/50/90 % of the
runs (sampled from /proc every 0.2 s), analyse's peak RSS, and the disk the campaign directory
takes (``du``: logs, ledger, report). Each campaign is deleted before the next one starts.

Run: ``nice -n 10 python benchmarks/bench_scale.py [--max 100000] [--work DIR]`` (DIR needs
~33 kB of disk a point; default a temporary folder).

Last measured 2026-12-03, the 2-core machine loaded 7–12 by other jobs (wall times 2–5× idle)::

    points     run [s]  runner peak  runner at 10/50/90 %     status [s] resume [s] analyse [s] analyse peak  disk
     1,000      5.8        46 MB  46 MB / 46 MB / not sampled       0.17       1.22        10.0       141 MB  34 MB
    10,000     51.4        61 MB     60 MB / 61 MB / 61 MB       0.55       9.94        24.5       193 MB  326 MB
    99,856    314.3       171 MB  133 MB / 133 MB / 133 MB       0.16      20.80        58.9       293 MB  3,196 MB

(``resume`` then re-planned every point; it now re-plans only when the plan's inputs changed.)
``--synthetic 1000000`` adds ``status``/``resume``/``analyse`` on synthetic 10^6-row ledgers
(:mod:`synthetic_ledger`). Before the seal (:mod:`labrunner.campaign.seal`), measured 2026-12-03,
load 3–4: status 0.58–0.87 s, resume of the finished campaign 8.9–9.7 s / 431 MB. After it,
measured 2026-12-03 08:00–08:13, load 3–9 (a test run sharing the cores for part of it)::

    finished campaign:     status 0.57 s / 36 MB;  resume, sealed 1.26 s / 41 MB;
                           resume after a crash (not sealed: every check, one listing) 11.8 s / 151 MB
    half-way interrupted:  status 0.35 s / 36 MB;  resume until its first batch is claimed:
                           sealed 2.76 s / 325 MB, after a crash 9.34 s / 329 MB

and at 08:17, load ~2: the finished campaign's sealed resume 0.37–0.42 s / 43 MB (0.27 s with
Python's bytecode cache, which this machine's environment turns off), status 0.34–0.40 s, resume
after a crash 7.3–7.9 s / 155 MB. The sealed resume is one ``stat`` and the state counts (~0.1 s) after
~0.45 s of imports; after a crash it still runs every check that reads the 1.1 GB ledger
(quick_check, the ids' checksum, the parameters: ~3–5 s) and lists runs/. An interrupted
campaign's resume then reads its 5×10^5 planned rows to cut them into batches (the scheduler's
design: ~2 s and ~300 MB here), so it does not start within a second.

Since then the batches are cut from a partial index of the planned points (8 bytes a point, read
by keyset pages; a batch's rows read as it is submitted) and a crashed session's journal
(:mod:`labrunner.campaign.journal`) lets ``resume`` settle only its claimed points, the checks that
read every row and the listing of runs/ moved to the resumed session's end. ``resume`` of the
half-way interrupted campaign until its first batch is claimed, the same two ledgers reused
(built 10:29 with ``synthetic_ledger.make``, the plan-inputs digest restamped after each code
change), ``/usr/bin/time -v``, three runs each, median wall (range), CPU = user + sys, peak RSS;
2026-12-03, the machine shared with a niced Dask campaign and two other engineers' jobs::

    sealed:                               1.06 s (1.05–1.09), 49 MB, load ~2.5 (10:55); 1.18 s (1.13–1.67), load ~1.5 (10:57)
                                          2.34 s / CPU 0.66 s at load 7 (11:01); 2.81 s / CPU 0.63 s at load 14 (11:12);
                                          4.83 s / CPU 0.75 s at load 10 with a test run (11:21)
    after a crash (its journal, 2000      1.29 s (1.24–1.34), 50 MB, load ~2.3 (10:55); 1.38 s (1.17–1.39) (10:57)
    points claimed by the dead session):  2.97 s / CPU 0.78 s at load 7; 3.86 s / CPU 0.92 s at load 15;
                                          6.27 s / CPU 1.04 s at load 10 with a test run

With the final code (JSON pages, and the rest of this change), 11:37 and 11:38 UTC::

    sealed:            0.85 s (0.73–0.93), CPU 0.59 s, 51 MB at load 6.4;  1.26 s (1.11–2.03), CPU 0.84 s at load 4.9
    after a crash:     0.96 s (0.92–1.23), CPU 0.78 s, 50 MB at load 6.4;  1.35 s (1.13–1.37), CPU 1.12 s at load 4.9
    status:            0.34 s (0.31–0.34), 36 MB

(was 2.76 s / 325 MB sealed and 9.34 s / 329 MB after a crash, above). The 10:55–10:57 runs read
the planned points' seq row by row (~0.37 s); the JSON pages take ~0.14 s (the same index,
measured alone). About 0.4 s of each is imports; on this shared machine the same command varied
by 50 % from one minute to the next, so sub-second is reached on some runs, not on all. The first
open for writing of a ledger made before the index builds it once (5.2 s for this one, load ~8).
The finished campaign, 11:32–11:36, load 7.5–10::

    resume, sealed                                   0.76 s (0.74–0.78), CPU 0.41 s, 42 MB
    resume after a crash, its journal (nothing to    22.6 s (17.7–23.6), CPU 9.3 s, 203 MB
      settle; the end-of-session check the crash cut short: every row, one listing)
    resume after a crash, no journal (full path)     22.6 s (18.5–24.7), CPU 8.3 s, 151 MB

The end-of-session check ran its row-reading ledger checks on the writing connection until
11:33 (CPU 12.2 s in the same case; 5.5 rather than 3.4 s of it for those checks, measured alone).
A finished campaign's resume after a crash therefore stays at the full path's cost: the check
the crash cut short is what would catch a log deleted or the ledger damaged during that session.

``analyse --workers 2`` of the finished synthetic campaign (its logs hard-linked, their
fingerprints in the ledger), measured 2026-12-03 08:24 UTC before the seal was merged, load 2–3
with a test run sharing the cores::

    first analyse   148.4 s, peak 559 MB (the analysing process, VmHWM; 1072 MB with the drawing child, sampled)
    second analyse  110.3 s, peak 558 MB

and after the maps became cells (a raster above ~45 × 45) and the table's text columns one Arrow
chunk each, measured 2026-12-03 11:04–11:14 UTC, load 5–11, and again at 11:22–11:32 after
main's merge (logs proved by one stat), load 8–13 (other jobs; wall times 2–3× those above)::

    first analyse   270.8 / 376.5 s, peak 489 / 485 MB (the analysing process, VmHWM)
    second analyse  335.0 / 229.6 s, peak 478 / 482 MB
    every run: the drawing child 83 MB, its child (both 1000 × 1000 maps) 242 MB

(each process's VmHWM, sampled every 0.2 s: ``analyse --workers 2`` of a ``synthetic_ledger.make``
directory, the report deleted before the first).

Before (same ledger size): the metrics table alone (``open_campaign(...).table()``) peaked at
1.03 GB (571 MB streaming the ledger, 302 MB the table), and a first ``analyse`` read every log's
metadata to prove its point (~0.8 ms a log: ~13 min at 10^6, not run). The 500 MB target is now
met, narrowly: imports ~115 MB, the table 292 MB, the rest transient. The real 10^6-point campaign
(README) peaked at 573 MB before these changes and was not measured again.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_campaign import _mb, campaign, timed  # noqa: E402


def _grid(n: int) -> tuple[int, int]:
    """γ × k_p counts whose product is ``n`` (10^3: 40 × 25, as bench_campaign's)."""
    if n == 1000:
        return 40, 25
    side = math.isqrt(n)
    return side, n // side


def _quick(args: list[str], cwd: Path, repeat: int) -> float:
    """Median wall time [s] of ``repeat`` runs of a short command (fresh processes)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(args, cwd=cwd, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _disk_mb(path: Path) -> float:
    out = subprocess.run(["du", "-sk", str(path)], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[0]) / 1024


def scale(work: Path, n: int, repeat: int) -> dict:
    n_gamma, n_kp = _grid(n)
    n = n_gamma * n_kp
    name = f"scale{n}"
    path = work / f"{name}.toml"
    path.write_text(campaign(name, n_gamma, n_kp))
    out = work / name
    cli = [sys.executable, "-m", "labrunner"]
    run = timed([*cli, "run", str(path), "--out", str(out), "--workers", "2"], work, out / "ledger.sqlite", n)
    status_s = _quick([*cli, "status", str(out)], work, repeat)
    resume_s = _quick([*cli, "resume", str(out)], work, repeat)
    analysis = timed([*cli, "analyse", str(out), "--workers", "2"], work)
    runs = sum(1 for _ in os.scandir(out / "runs"))
    disk = _disk_mb(out)
    shutil.rmtree(out)
    return {
        "n": n,
        "run": run,
        "status_s": status_s,
        "resume_s": resume_s,
        "analyse": analysis,
        "disk_mb": disk,
        "logs": runs,
    }


#: ``resume`` of DIR that stops as its first batch is claimed (nothing is written): how long a
#: resume of an unfinished campaign takes to start running.
UNTIL_FIRST_BATCH = (
    "import os, sys\n"
    "from labrunner.campaign.ledger import Ledger\n"
    "Ledger.claim = lambda self, ids: os._exit(0)\n"
    "from labrunner.cli import main\n"
    "raise SystemExit(main(['resume', sys.argv[1], '--workers', '2']))  # a refusal fails the timing\n"
)


#: How ``resume`` finds the directory: "sealed" as a session that ended cleanly leaves it; "crash"
#: as a session killed with :data:`IN_FLIGHT` points claimed (its batches running) leaves it, its
#: session journal kept (:mod:`labrunner.campaign.journal`); "full" with neither seal nor journal
#: (a crash on another boot, or left by a labrunner before the journal): every check, one listing.
STATES = ("sealed", "crash", "full")
IN_FLIGHT = 2000


def prepare(directory: Path, state: str) -> None:
    """Leave ``directory`` as ``state`` (:data:`STATES`) says, as the session before would have."""
    from labrunner.campaign import journal, seal
    from labrunner.campaign.ledger import Ledger

    with Ledger.open(directory, verify=False) as ledger:
        claimed = [r[0] for r in ledger.db.execute("SELECT id FROM points WHERE state = 'claimed'")]
        ledger.unclaim(claimed)  # a timed resume stopped at its first claim: that batch never ran
        if state == "sealed":
            journal.end(ledger)
            assert seal.seal(ledger), f"{directory} is not consistent"
            return
        seal.clear(ledger)
        if state == "full":
            journal.end(ledger)
            return
        journal.begin(ledger, ledger.counts())  # as the session did when it started
        claimed = ledger.db.execute("SELECT id FROM points WHERE state = 'planned' ORDER BY seq LIMIT ?", (IN_FLIGHT,))
        ids = [r[0] for r in claimed]
        if ids:
            ledger.claim(ids)  # its running batches, their logs not yet written


def synthetic(work: Path, n: int, repeat: int) -> None:
    """``status`` and ``resume`` of a finished synthetic campaign of ``n`` points
    (:mod:`synthetic_ledger`: real ids, parameters and plan-inputs digest; a small real run's rows
    and logs repeated, the logs hard-linked, their fingerprints in the ledger), and of one
    interrupted half-way (``resume`` until its first batch is claimed). ``resume`` as after a
    session that ended cleanly (sealed: :mod:`labrunner.campaign.seal`) and as after a crash (not
    sealed). ``repeat`` of each, fresh processes; the median wall time and the largest peak RSS. Then
    ``analyse --workers 2`` of the finished one, twice (the first proves every log by the ledger's
    fingerprints; the second also has the first's report): wall time, the analysing process's peak
    RSS (the kernel's high-water mark) and its tree's (with the drawing child), sampled."""
    import synthetic_ledger

    n_gamma, n_kp = _grid(n)
    cli = [sys.executable, "-m", "labrunner"]
    for name, finished in (("synthetic", 1.0), ("interrupted", 0.5)):
        t0 = time.perf_counter()
        directory = synthetic_ledger.make(work, name, n_gamma, n_kp, finished=finished)
        built = time.perf_counter() - t0
        resume = (
            [*cli, "resume", str(directory)]
            if finished == 1.0
            else [sys.executable, "-c", UNTIL_FIRST_BATCH, str(directory)]
        )
        cases = [("status", [*cli, "status", str(directory)], None)]
        cases += [(f"resume ({state})", resume, state) for state in STATES]
        for label, command, state in cases:
            runs = []
            for _ in range(repeat):
                if state is not None:
                    prepare(directory, state)
                runs.append(timed(command, work))
            print(
                f"{n_gamma * n_kp:>9,} points, {finished:.0%} finished (synthetic ledger, built in {built:.0f} s): "
                f"{label}{'' if finished == 1.0 or state is None else ' (until the first batch)'} "
                f"{statistics.median(r['wall_s'] for r in runs):.2f} s, peak {_mb(max(r['peak_parent_kb'] for r in runs))}",
                flush=True,
            )
        if finished == 1.0:
            for which in ("first", "second"):
                r = timed([*cli, "analyse", str(directory), "--workers", "2"], work)
                print(
                    f"{n_gamma * n_kp:>9,} points (synthetic ledger): {which} analyse {r['wall_s']:.1f} s, "
                    f"peak {_mb(r['hwm_parent_kb'])} (with the drawing child: {_mb(r['peak_total_kb'])} sampled)",
                    flush=True,
                )
        shutil.rmtree(directory)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--min", type=int, default=1000, help="smallest campaign (points; default 1000)")
    parser.add_argument("--max", type=int, default=100_000, help="largest campaign (points; default 100000)")
    parser.add_argument(
        "--synthetic", type=int, default=0, help="also status/resume/analyse on a synthetic ledger of this many points"
    )
    parser.add_argument("--work", type=Path, default=None, help="folder for the campaigns (default: a temporary one)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each status/resume, the median (default 3)")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_scale_", dir=args.work))
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
    print(
        "points     run [s]  runner peak  runner at 10/50/90 %     status [s] resume [s] analyse [s] analyse peak  disk"
    )
    try:
        n = args.min
        while n <= args.max:
            r = scale(work, n, args.repeat)
            run, analysis = r["run"], r["analyse"]
            at = " / ".join(_mb(run["parent_at"].get(p)) for p in (10, 50, 90))
            print(
                f"{r['n']:>9,}  {run['wall_s']:7.1f}  {_mb(run['peak_parent_kb']):>11}  {at:>24}  "
                f"{r['status_s']:9.2f}  {r['resume_s']:9.2f}  {analysis['wall_s']:10.1f}  "
                f"{_mb(analysis['peak_parent_kb']):>11}  {r['disk_mb']:,.0f} MB ({r['disk_mb'] * 1024 / r['n']:.1f} kB a point)",
                flush=True,
            )
            n *= 10
        if args.synthetic:
            synthetic(work, args.synthetic, args.repeat)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
