"""Benchmarks of labrunner.differentiators (issue 2 targets), printing figures.

- design + weights (fresh design, mid-point, order 1) for n_s up to 10⁴: target ≤ 5 ms;
- StreamingFIR with n_s = 261 (α = β = 4, ω_c = 840 rad/s at 32 kHz) over B = 1000 runs:
  target ≤ 50 µs per tick (shared taps); per-run taps and B = 1 (L = 14) for reference.

Run: python benchmarks/bench_differentiators.py. Times are the best of several rounds in CPU time
of this process (on a shared host, time spent descheduled is not the code's cost), one BLAS thread.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core, as the CPU time counts all threads

import time  # noqa: E402

import numpy as np  # noqa: E402

from labrunner.differentiators import StreamingFIR, design  # noqa: E402


def best_of(fn, repeat: int, number: int) -> float:
    """Best mean CPU time of ``number`` calls over ``repeat`` rounds [s]."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        for _ in range(number):
            fn()
        best = min(best, (time.process_time() - t0) / number)
    return best


def bench_design() -> None:
    print("design + weights(1), fresh design each call (target <= 5 ms at n_s = 1e4)")
    for n_s in (100, 261, 1000, 10_000):
        for method in ("midpoint", "trapezoidal", "analytic"):
            for alpha, beta, N in ((4, 4, 0), (2.5, 7, 2), (150, 150, 0)):
                t = best_of(
                    lambda: design(alpha=alpha, beta=beta, N=N, window=n_s / 32000, fs=32000, method=method).weights(1),
                    5,
                    5,
                )
                print(
                    f"  n_s = {n_s:6d}  {method:11s}  alpha = {alpha:5g}, beta = {beta:5g}, N = {N}:  {t * 1e3:7.3f} ms"
                )


def bench_streaming() -> None:
    d = design(alpha=4, beta=4, omega_c=840, fs=32000)
    taps = d.weights(1)
    rng = np.random.default_rng(0)
    print(f"StreamingFIR.step, n_s = {d.n_s} (target <= 50 us per tick at B = 1000)")
    cases = [
        ("shared taps (L,)", taps, 1000),
        ("per-run taps (B, L)", taps[None, :] * rng.uniform(0.5, 1.5, (1000, 1)), 1000),
        (
            "bank (B, 3, L) shared",
            np.broadcast_to(np.stack([d.weights(n) for n in range(3)]), (1000, 3, taps.size)),
            1000,
        ),
        ("B = 1, L = 14", design(alpha=9, beta=9, omega_c=200, fs=200).weights(1), 1),
    ]
    for label, t, batch in cases:
        fir = StreamingFIR(t)
        fir.reset(batch, fill=0.0)
        x = rng.normal(size=batch)
        sec = best_of(lambda: fir.step(x), 5, 2000 if batch == 1 else 300)
        print(f"  {label:24s} B = {batch:5d}:  {sec * 1e6:8.2f} us/tick")
    # The floor on this machine: one BLAS matrix-vector product over the (L, B) history, nothing else.
    block = rng.normal(size=(taps.size, 1000))
    sec = best_of(lambda: taps @ block, 5, 300)
    print(f"  {'reference: bare taps @ (L, B) block':36s}:  {sec * 1e6:8.2f} us")


if __name__ == "__main__":
    bench_design()
    bench_streaming()
