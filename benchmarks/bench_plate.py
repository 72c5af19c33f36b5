"""Speed of the plate twin and its closed loops at 32 kHz (issue: ≥ 10× real time per core for B ≥ 32).

"× real time" is run-seconds simulated per wall-clock second on one core: B runs of T seconds
in W seconds of wall time give B·T/W. Run: ``python benchmarks/bench_plate.py [--batch 32]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from labrunner.control.factory import build  # noqa: E402
from labrunner.rigs.registry import load_rig  # noqa: E402

FS = 32_000.0
LIFT = {"kind": "setpoints", "levels": [5.5e-3, 2e-3], "transition": 0.3, "hold": [0.0, 0.2]}
POINTS = {
    "MBC (eq. 7, 10-12)": {"controller": {"kind": "plate-mbc"}, "reference": LIFT},
    "MFC v, α=β=4, ω_c=840 (n_s=261)": {
        "controller": {"kind": "plate-mfc", "input": "v", "gamma": 1.0, "k_p": 5000.0, "k_d": 195.0},
        "differentiator": {"alpha": 4, "omega_c": 840.0},
        "reference": LIFT,
    },
}


def bench_twin(batch: int, seconds: float) -> tuple[float, float]:
    """Open loop at a constant current (plate on the screws: the contact path, the dearer one)."""
    rig = load_rig("plate-sim")
    rig.reset(batch, np.arange(batch), FS)
    u = np.full((batch, 4), 3.0)
    K = int(seconds * FS)
    t0 = time.perf_counter()
    for _ in range(K):
        rig.step(u)
    wall = time.perf_counter() - t0
    return wall / K * 1e6, batch * seconds / wall


def bench_loop(point: dict, batch: int, seconds: float) -> tuple[float, float]:
    """Controller + twin, tick by tick, reference evaluated in one block beforehand (as the engine does)."""
    rig = load_rig("plate-sim")
    controller, reference = build([point] * batch, rig.info, FS)
    K = int(seconds * FS)
    R = reference.evaluate(np.arange(K) / FS)
    y = rig.reset(batch, np.arange(batch), FS)
    controller.reset(y)
    t0 = time.perf_counter()
    for k in range(K):
        y = rig.step(controller.step(y, R[k]))
    wall = time.perf_counter() - t0
    return wall / K * 1e6, batch * seconds / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 32, 128])
    parser.add_argument("--seconds", type=float, default=0.5, help="simulated seconds per case")
    args = parser.parse_args()
    print(f"plate at {FS / 1000:g} kHz, {args.seconds:g} s simulated per case, one thread")
    print(f"{'case':40s} {'B':>5s} {'µs/tick':>9s} {'× real time':>12s}")
    for B in args.batch:
        us, x = bench_twin(B, args.seconds)
        print(f"{'twin alone':40s} {B:5d} {us:9.1f} {x:12.1f}")
        for name, point in POINTS.items():
            us, x = bench_loop(point, B, args.seconds)
            print(f"{'closed loop, ' + name:40s} {B:5d} {us:9.1f} {x:12.1f}")


if __name__ == "__main__":
    main()
