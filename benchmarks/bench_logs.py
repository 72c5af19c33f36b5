"""Run-log speed: write and read a 3 s, 32 kHz plate-like run with ten signals and its full-rate
per-sample channel (targets: write ≤ 60 ms, read ≤ 20 ms), and the per-file cost of 1000 motor
runs (200 Hz × 5 s, eight signals) written as a worker writes a batch: the shared part (header,
schemas, channels, rig record, campaign file) encoded once, the run's records per file (target
≤ 1 ms per run).

    python benchmarks/bench_logs.py [--repeat 20] [--motor-runs 1000] [--dir /dev/shm]

``--dir`` chooses where the files go (default: the system's temporary directory); a tmpfs such
as /dev/shm takes the disk out of the figures.

Last measured (2-core machine, load average 0.3–0.7, ext4, best of two rounds; before the per-file
records were encoded by ``mcap_records`` and chunks compressed in one call, same machine and
hour): plate full rate write 41 ms CPU (was 45), thinned 13.3 ms (was 15.3), read 12 ms; motor
0.67 ms CPU per file in batches of 64 (was 0.76), 0.90 ms alone (was 0.94). These synthetic motor
runs are noisy (168 kB a file); a real campaign's logs (33 kB on average, half of the runs
aborted) cost 0.33 ms CPU each on a tmpfs (0.43 ms before).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from labrunner.logs import BatchPrefixes, read_metadata, read_run, write_run

OUTCOME = {"status": "completed", "monitor": None, "time": None, "value": None, "threshold": None, "message": ""}


def plate_run(fs: float = 32000.0, duration: float = 3.0, seed: int = 0) -> dict[str, np.ndarray]:
    """Three air gaps [m] (lift 5.5 → 2 mm, 150 Hz resonance, noise), their references, four currents [A]."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(fs * duration)) / fs
    s = np.clip(t / 0.5, 0, 1)
    ref = 5.5e-3 - 3.5e-3 * s**3 * (10 - 15 * s + 6 * s**2)
    out = {}
    for j in range(3):
        out[f"h{j}"] = ref + 2e-5 * np.sin(942.0 * t + j) * np.exp(-t) + 1e-6 * rng.standard_normal(t.size)
        out[f"ref_h{j}"] = ref
    for j in range(4):
        out[f"i{j}"] = 3.0 + 0.5 * s + 0.05 * rng.standard_normal(t.size)
    return out


def motor_run(seed: int, fs: float = 200.0, duration: float = 5.0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(round(fs * duration)) / fs
    omega = 40 * np.tanh(t) + 0.1 * rng.standard_normal(t.size)
    theta = np.round(np.cumsum(omega) / fs / (2 * np.pi / 2048)) * (2 * np.pi / 2048)
    return {
        "theta": theta,
        "omega": omega,
        "ref_omega": 40 * np.tanh(t),
        "e_omega": omega - 40 * np.tanh(t),
        "u": 3 + 0.2 * rng.standard_normal(t.size),
        "f_hat_omega": -39.44 * omega,
        "e_hat_omega": 0.01 * rng.standard_normal(t.size),
        "de_hat_omega": 0.1 * rng.standard_normal(t.size),
    }


def meta(i: int) -> dict:
    """The records a worker writes per run (run, config, parameters, metrics)."""
    config = {
        "controller": {"kind": "mfc1", "output": "velocity", "k_p": 50.0, "gamma": 108.55},
        "differentiator": {"alpha": 9, "beta": 9, "omega_c": 200.0},
        "reference": {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 1.0, "hold": 1.0},
        "campaign": {"name": "bench", "rig": "dcmotor-sim", "fs": 200.0, "duration": 5.0, "seed": 0},
    }
    return {
        "run": {
            "campaign": "bench",
            "point_id": f"{i:016x}",
            "attempt": 1,
            "seed": i,
            "rig": "dcmotor-sim",
            "duration": 5.0,
            "host": "bench",
            "pid": 1,
            "start_time": 1.7e9,
        },
        "config": config,
        "parameters": {"controller.gamma": 108.55, "controller.k_p": 50.0},
        "metrics": {"rms_error": 0.5, "input_energy": 12.0, "max_abs_input": 3.2, "n_samples": 1000},
    }


RIG = {
    "kind": "dcmotor",
    "parameters": {"a": 39.44, "b": 108.55, "J": 1e-4},
    "limits": {"u": [-12.0, 12.0]},
    "noise": {"omega": 0.01},
    "faults": {},
    "safety": {"du_dt": 120.0},
}
CAMPAIGN_FILE = ("[campaign]\nname = 'bench'\n" + "# comment line of a campaign file\n" * 40).encode()


def timed(fn, *args, **kwargs) -> tuple[float, float]:
    """(wall, CPU) seconds of one call; CPU time is what counts when other processes share the cores."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn(*args, **kwargs)
    return time.perf_counter() - w0, time.process_time() - c0


def figures(samples: list[tuple[float, float]]) -> str:
    wall, cpu = np.array(samples).T * 1e3
    return f"median {np.median(wall):5.1f} ms wall (min {wall.min():5.1f}), {np.median(cpu):5.1f} ms CPU"


def bench_plate(directory: Path, repeat: int) -> None:
    signals = plate_run()
    raw_mb = sum(v.nbytes for v in signals.values()) / 1e6
    print(
        f"plate run: 3 s at 32 kHz, {len(signals)} signals, {raw_mb:.1f} MB of float64 (targets: write 60 ms, read 20 ms)"
    )
    for samples_hz in (None, 500.0):
        writes, reads = [], []
        for i in range(repeat):
            path = directory / f"plate_{samples_hz}_{i}.mcap"
            writes.append(
                timed(
                    write_run,
                    path,
                    metadata=meta(i),
                    fs=32000.0,
                    signals=signals,
                    outcome=OUTCOME,
                    samples_hz=samples_hz,
                )
            )
            reads.append(timed(read_run, path))
        assert np.array_equal(read_run(path).frame["i3"].to_numpy(), signals["i3"])
        rate = "full rate (default)" if samples_hz is None else f"thinned to {samples_hz:g} Hz"
        print(f"  /run/samples {rate}, file {path.stat().st_size / 1e6:.2f} MB")
        print(f"    write {figures(writes)}")
        print(f"    read  {figures(reads)}")


def bench_motor(directory: Path, n_runs: int) -> None:
    runs = [motor_run(i) for i in range(n_runs)]
    print(
        f"motor runs: {n_runs} × 1000 samples × {len(runs[0])} signals (200 Hz, 5 s), every sample in /run/samples "
        "(target: write 1 ms per run)"
    )
    for batch in (64, 1):
        sub = directory / f"motor_{batch}"
        sub.mkdir()

        def write_all() -> None:
            for i, signals in enumerate(runs):
                if i % batch == 0:  # a worker's batch: the shared part once
                    prefixes = BatchPrefixes(200.0, {"rig": RIG}, {"campaign.toml": CAMPAIGN_FILE})
                write_run(
                    sub / f"{i:05d}.mcap",
                    metadata=meta(i),
                    signals=signals,
                    outcome=OUTCOME,
                    prefix=prefixes.get(list(signals), None),
                    start_time=1.7e9,
                )

        wall, cpu = timed(write_all)
        size = sum(p.stat().st_size for p in sub.iterdir()) / n_runs / 1e3
        print(
            f"  batches of {batch:3d}: write {1e3 * wall / n_runs:5.2f} ms/file wall, {1e3 * cpu / n_runs:5.2f} ms/file CPU"
            f" ({n_runs / cpu:4.0f} files per CPU-second), {size:.0f} kB/file"
        )
    paths = sorted(sub.iterdir())
    wall, cpu = timed(lambda: [read_metadata(p)["outcome"] for p in paths])
    print(f"  read_metadata (outcome): {1e3 * wall / n_runs:5.2f} ms/file wall, {1e3 * cpu / n_runs:5.2f} ms/file CPU")
    wall, cpu = timed(lambda: [read_run(p) for p in paths[:200]])
    print(f"  read_run:                {1e3 * wall / 200:5.2f} ms/file wall, {1e3 * cpu / 200:5.2f} ms/file CPU")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--motor-runs", type=int, default=1000)
    parser.add_argument("--dir", default=None, help="parent directory of the files written")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        print(f"files in {tmp}")
        bench_plate(Path(tmp), args.repeat)
        bench_motor(Path(tmp), args.motor_runs)


if __name__ == "__main__":
    main()
