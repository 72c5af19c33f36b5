"""Speed of the stability solver: one spectral-abscissa evaluation (target <= 5 ms) and a 50 x 50
(gamma, k_p) map of the DC-motor loops (target <= 15 s on one core). Prints the figures.

Run as ``python benchmarks/bench_stability.py [--size N] [--repeat N]`` (pin to one core with ``taskset -c 0``
if wanted); ``--size``/``--repeat`` shrink the maps and the per-call loop for a smoke run (the targets are
for the defaults, 50 and 300).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from labrunner.stability import abscissa_map, bounds, case_quasipolynomial, spectral_abscissa

A, B, DELAY = 39.44, 108.55, 0.035


def per_call_ms(fn, repeat: int) -> float:
    fn()
    start = time.perf_counter()
    for _ in range(repeat):
        fn()
    return (time.perf_counter() - start) / repeat * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=50, help="cells per side of the maps (default 50)")
    parser.add_argument("--repeat", type=int, default=300, help="evaluations per spectral-abscissa figure")
    args = parser.parse_args()
    n = args.size
    first = case_quasipolynomial("mfc1-motor", gamma=B, delay=DELAY, a=A, b=B, k_p=60.0)
    second = case_quasipolynomial("mfc2-motor", gamma=B, delay=DELAY, a=A, b=B, k_p=400.0, k_d=40.0)
    neutral = case_quasipolynomial("mfc1-motor", gamma=0.8 * B, delay=DELAY, a=A, b=B, k_p=60.0, neutral=True)
    for name, qp in (("first order (2.45)", first), ("second order (2.57)", second), ("neutral (A.11)", neutral)):
        print(
            f"spectral abscissa, {name:20s}: {per_call_ms(lambda q=qp: spectral_abscissa(q), args.repeat):6.3f} ms/eval (target 5 ms)"
        )

    gammas = np.linspace(0.5 * B, 1.5 * B, n)
    for case, k_p, k_d in (
        ("mfc1-motor", np.linspace(-20.0, 200.0, n), None),
        ("mfc2-motor", np.linspace(-100.0, 1500.0, n), 40.0),
    ):
        start = time.perf_counter()
        m = abscissa_map(
            lambda g, kp, c=case, kd=k_d: case_quasipolynomial(c, gamma=g, delay=DELAY, a=A, b=B, k_p=kp, k_d=kd),
            gammas,
            k_p,
        )
        print(
            f"{n} x {n} map, {case:10s}: {time.perf_counter() - start:6.2f} s (target 15 s at 50 x 50), "
            f"{np.mean(m < 0):.0%} stable cells"
        )

    start = time.perf_counter()
    bounds("mfc2-motor", gamma=B, delay=DELAY, a=A, b=B, k_d=40.0, numeric=True)
    print(f"bounds(mfc2-motor, numeric=True): {time.perf_counter() - start:6.3f} s")
    start = time.perf_counter()
    for g in gammas:
        bounds("mfc2-motor", gamma=g, delay=DELAY, a=A, b=B, k_d=40.0)
    print(f"closed-form bounds, mfc2-motor: {(time.perf_counter() - start) / len(gammas) * 1e3:6.3f} ms/call")


if __name__ == "__main__":
    main()
