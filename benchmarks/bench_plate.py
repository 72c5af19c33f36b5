"""Speed of the plate twin and its closed loops at 32 kHz (issue 5: ≥ 10× real time per core for B ≥ 32).

"× real time" is run-seconds simulated per second of one core: B runs of T seconds in W seconds
give B·T/W. Rows: the twin alone; controller and twin tick by tick (the loop without anything
around it); and the figure that matters for a campaign, :func:`labrunner.engine.run_batch` with
the rig file's safety monitors (reference, controller, safety, twin, signal collection and the
per-run results, as a campaign worker runs a batch, reporting its ticks to a live-progress slot;
MCAP writing is bench_logs.py's).

W is the best of ``--repeat`` rounds in CPU time of this process (on a shared host, time spent
descheduled is not the code's cost); the median wall-clock time is printed beside it.
Run: ``python benchmarks/bench_plate.py [--batch 1 32 128] [--seconds 0.5] [--repeat 3]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import argparse  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from labrunner import engine  # noqa: E402
from labrunner.campaign import live  # noqa: E402
from labrunner.control.factory import build  # noqa: E402
from labrunner.rigs.registry import load_rig  # noqa: E402

FS = 32_000.0
TARGET = 10.0  # × real time per core, B ≥ 32
LIFT = {"kind": "setpoints", "levels": [5.5e-3, 2e-3], "transition": 0.3, "hold": [0.0, 0.2]}
POINTS = {
    "MBC (eq. 7, 10-12)": {"controller": {"kind": "plate-mbc"}, "reference": LIFT},
    "MFC v, α=β=4, ω_c=840 (n_s=261)": {
        "controller": {"kind": "plate-mfc", "input": "v", "gamma": 1.0, "k_p": 5000.0, "k_d": 195.0},
        "differentiator": {"alpha": 4, "omega_c": 840.0},
        "reference": LIFT,
    },
}


def timed(fn: Callable[[], None], repeat: int) -> tuple[float, float]:
    """Best CPU seconds and median wall seconds of ``repeat`` calls of ``fn``."""
    cpu, wall = [], []
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return min(cpu), float(np.median(wall))


def twin(batch: int, ticks: int) -> Callable[[], None]:
    """Open loop at a constant current (plate on the screws: the contact path, the dearer one)."""
    rig = load_rig("plate-sim")
    u = np.full((batch, 4), 3.0)

    def run() -> None:
        rig.reset(batch, np.arange(batch), FS)
        for _ in range(ticks):
            rig.step(u)

    return run


def loop(point: dict, batch: int, ticks: int) -> Callable[[], None]:
    """Controller + twin, tick by tick, reference evaluated in one block beforehand (as the engine does)."""
    rig = load_rig("plate-sim")
    controller, reference = build([point] * batch, rig.info, FS)
    R = reference.evaluate(np.arange(ticks) / FS)

    def run() -> None:
        y = rig.reset(batch, np.arange(batch), FS)
        controller.reset(y)
        for k in range(ticks):
            y = rig.step(controller.step(y, R[k]))

    return run


def campaign_batch(point: dict, batch: int, ticks: int) -> Callable[[], None]:
    """engine.run_batch with the rig file's [safety] section (air-gap and current bounds, run time)."""
    rig = load_rig("plate-sim")
    points = [point] * batch
    live.install(live.LiveTicks(1).array)  # as a pool worker's initializer does

    def run() -> None:
        results = engine.run_batch(
            points,
            rig,
            fs=FS,
            duration=ticks / FS,
            seeds=list(range(batch)),
            rig_safety=rig.config.safety,
            progress=live.hook(live.Address(0, 0)),
        )
        bad = [r.outcome.status for r in results if r.outcome.status != "completed"]
        assert not bad, f"benchmark runs must complete, got {bad[:3]}"

    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 32, 128])
    parser.add_argument("--seconds", type=float, default=0.5, help="simulated seconds per case")
    parser.add_argument("--repeat", type=int, default=3, help="rounds per case; the best CPU time is reported")
    args = parser.parse_args()
    ticks = int(args.seconds * FS)
    print(f"plate at {FS / 1000:g} kHz, {args.seconds:g} s simulated per case, one thread, best of {args.repeat}")
    print(f"{'case':58s} {'B':>4s} {'µs/tick':>8s} {'× real time':>11s} {'(wall)':>7s}")
    for B in args.batch:
        cases = [("twin alone", twin(B, ticks))]
        for name, point in POINTS.items():
            cases.append((f"controller + twin, {name}", loop(point, B, ticks)))
        for name, point in POINTS.items():
            cases.append((f"engine.run_batch + safety, {name}", campaign_batch(point, B, ticks)))
        for name, fn in cases:
            cpu, wall = timed(fn, args.repeat)
            x = B * args.seconds / cpu
            verdict = "" if B < 32 or name == "twin alone" else ("ok" if x >= TARGET else "MISSED")
            print(f"{name:58s} {B:4d} {cpu / ticks * 1e6:8.1f} {x:11.1f} {B * args.seconds / wall:7.1f} {verdict}")


if __name__ == "__main__":
    main()
