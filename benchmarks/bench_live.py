"""What ``labrunner run --live`` costs the campaign (issue 34, part 2); prints figures.

A 1000-point motor campaign (40 × 25, 5 s runs at 200 Hz, ``--workers 2``) run as a user runs it,
in fresh processes, under four conditions, interleaved, ``--trials`` times each:

1. without ``--live`` (nothing listens);
2. ``--live``, no client connected;
3. ``--live`` with one client that subscribes to every channel and decodes every message (in this
   process: its CPU is not the runner's);
4. as 3, plus a client that subscribes to every channel and never reads (its socket fills; the
   server drops its oldest messages).

Per condition: the median wall time and CPU time (the runner and its workers, from
``getrusage(RUSAGE_CHILDREN)``), and what the reading client received (messages by topic, MB).

Usage: ``python benchmarks/bench_live.py [--trials N] [--grid N_GAMMA N_KP]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

from motor_campaign import motor_campaign
from websockets.sync.client import connect

GRID = '"controller.gamma" = {{ log10 = [1.0, 3.0], num = {} }}\n"controller.k_p" = {{ log10 = [-1.0, 3.0], num = {} }}'
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _client(url: str, read: bool, got: Counter, ready: threading.Event, ended: threading.Event) -> None:
    """Subscribe to every channel; then decode every message until the server closes (``read``), or never
    read until the runner has ended (``ended``: a socket that is never read never sees the close)."""
    # a stalled client sends no pings, and does not wait out a close handshake it never reads
    kind = {"max_queue": None} if read else {"max_queue": 1, "ping_interval": None, "close_timeout": 0.1}
    with connect(url, subprotocols=SUBPROTOCOLS, max_size=None, **kind) as ws:
        json.loads(ws.recv())  # serverInfo
        channels: dict[int, str] = {}
        while len(channels) < 4:
            message = json.loads(ws.recv())
            if message["op"] == "advertise":
                channels.update({c["id"]: c["topic"] for c in message["channels"]})
        ids = dict(enumerate(channels, start=1))
        subscribe = [{"id": i, "channelId": c} for i, c in ids.items()]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subscribe}))
        ready.set()
        if not read:
            ended.wait()  # the socket is never read
            return
        try:
            while True:
                frame = ws.recv()
                if isinstance(frame, bytes):
                    _, sub, _ = struct.unpack_from("<BIQ", frame)
                    json.loads(frame[13:])
                    got[channels[ids[sub]]] += 1
                    got["bytes"] += len(frame)
        except Exception:  # closed at the end of the session
            return


def trial(work: Path, condition: int, n: int, points: int) -> dict:
    out = work / f"c{condition}-{n}"
    args = [sys.executable, "-m", "labrunner", "run", "live.toml", "--out", str(out), "--workers", "2"]
    if condition > 1:
        args += ["--live", "127.0.0.1:0"]
    cpu0, t0 = _cpu(), time.perf_counter()
    proc = subprocess.Popen(args, cwd=work, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    got: Counter = Counter()
    threads, ended = [], threading.Event()
    if condition > 2:
        url = proc.stderr.readline().split()[1]
        for read in [True] if condition == 3 else [True, False]:
            ready = threading.Event()
            thread = threading.Thread(target=_client, args=(url, read, got, ready, ended), daemon=True)
            thread.start()
            ready.wait(30)
            threads.append(thread)
    _, err = proc.communicate(timeout=600)
    wall, cpu = time.perf_counter() - t0, _cpu() - cpu0
    ended.set()
    for thread in threads:
        thread.join(30)
    if proc.returncode != 0 or f"{points}/{points}" not in err:
        raise SystemExit(f"condition {condition}: exit {proc.returncode}: {err[-500:]}")
    return {"wall": wall, "cpu": cpu, "got": got}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--grid", type=int, nargs=2, default=[40, 25], metavar=("N_GAMMA", "N_KP"))
    args = parser.parse_args()
    trials, points = args.trials, args.grid[0] * args.grid[1]
    names = {
        1: "no --live",
        2: "--live, no client",
        3: "--live, one client reading",
        4: "--live, one reading, one never reading",
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "live.toml").write_text(
            motor_campaign("live", levels="[0.0, 20.0, 0.0]", hold=0.5, duration=5.0, grid=GRID.format(*args.grid))
        )
        print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
        results: dict[int, list[dict]] = {c: [] for c in names}
        for n in range(trials):
            for condition in names:
                results[condition].append(trial(work, condition, n, points))
        print(f"{points}-point motor campaign, --workers 2, median of {trials} trials (interleaved):")
        for condition, name in names.items():
            runs = results[condition]
            wall = statistics.median(r["wall"] for r in runs)
            cpu = statistics.median(r["cpu"] for r in runs)
            got = runs[-1]["got"]
            seen = ", ".join(f"{t} {c}" for t, c in sorted(got.items()) if t != "bytes")
            extra = f"; the reader got {seen} ({got['bytes'] / 1e6:.1f} MB)" if got else ""
            print(f"  {name:40s} {wall:6.2f} s wall, {cpu:6.2f} s CPU{extra}")
        print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
