"""Speed of the sim twins and of a real-rig round trip through the emulator.

    python benchmarks/bench_rigs.py

Prints, per case, rig steps per second (one step advances the whole batch by one sample), run
samples per second (B × steps/s) and the real-time factor per run (run samples/s ÷ f_s).
"""

from __future__ import annotations

import time

import numpy as np

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.registry import load_rig


def bench(rig, batch: int, fs: float, inputs: np.ndarray, seconds: float = 2.0) -> tuple[float, float, float]:
    rig.reset(batch, np.arange(batch), fs)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for u in inputs:
            rig.step(u)
        n += len(inputs)
    steps = n / (time.perf_counter() - t0)
    return steps, steps * batch, steps * batch / fs


def report(name: str, figures: tuple[float, float, float]) -> None:
    steps, samples, realtime = figures
    print(f"{name:<44} {steps:>10.0f} steps/s {samples:>12.0f} run samples/s {realtime:>9.1f} x real time")


def main() -> None:
    rng = np.random.default_rng(0)
    for b in (1, 100):
        u = rng.uniform(-12, 12, (200, b, 1))
        report(f"dcmotor-sim, B = {b}, 200 Hz", bench(load_rig("dcmotor-sim"), b, 200.0, u))
    report(
        "dcmotor-frictionless, B = 100, 200 Hz",
        bench(load_rig("dcmotor-frictionless"), 100, 200.0, rng.uniform(-12, 12, (200, 100, 1))),
    )
    for b in (1, 32, 100):
        i = rng.uniform(0.4, 0.8, (400, b, 1))
        report(f"valve-sim, B = {b}, 4 kHz", bench(load_rig("valve-sim"), b, 4000.0, i))

    from labrunner.rigs.transports.emulator import Emulator, device_link, serve_on_pty, twin_for

    for interface, channel in (("udp_multicast", "239.74.163.2"), ("virtual", "bench")):
        config = config_from_dict(
            {
                "rig": {"kind": "can"},
                "parameters": {
                    "device": "dcmotor",
                    "interface": interface,
                    "channel": channel,
                    "port": 47001 if interface == "udp_multicast" else 0,
                    "node_id": 3,
                },
            }
        )
        with Emulator(twin_for(config), device_link(config), paced=False):
            rig = load_rig(config)
            report(
                f"can ({interface}) + emulator, B = 1, 200 Hz", bench(rig, 1, 200.0, rng.uniform(-12, 12, (200, 1, 1)))
            )
            rig.close()
    serial = {"rig": {"kind": "serial"}, "parameters": {"device": "dcmotor", "port": "", "baudrate": 115200}}
    name, emulator = serve_on_pty(twin_for(config_from_dict(serial)), paced=False)
    serial["parameters"]["port"] = name
    rig = load_rig(config_from_dict(serial))
    report("serial (pty) + emulator, B = 1, 200 Hz", bench(rig, 1, 200.0, rng.uniform(-12, 12, (200, 1, 1))))
    rig.close()
    emulator.stop()


if __name__ == "__main__":
    main()
