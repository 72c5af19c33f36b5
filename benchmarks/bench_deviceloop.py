"""Benchmark of the device loop: a 3 s plate run at 32 kHz and a 5 s motor run at 1 kHz, each one
point of a campaign run by `labrunner run` against `labrunner emulate --free-run` in another
process (the shipped rig files, moved onto python-can's udp_multicast, or a pty for serial).

Prints per case: wall time from `labrunner run` starting to the MCAP being published, the
device's compute time of the run (the emulated device is Python: slower than real time at
32 kHz), the transfer time (ACCEPT → VERDICT), the payload bytes moved each way, the frames the
host received, the retransmissions, and what the same bytes take on the rig file's real link by
the link-load model (docs/device-loop.md).

    python benchmarks/bench_deviceloop.py [--only plate-can|plate-serial|motor-can]
"""

from __future__ import annotations

import argparse
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from labrunner.logs import read_run  # noqa: E402
from labrunner.rigs.config import load_rig_config  # noqa: E402
from labrunner.rigs.transports import linkload  # noqa: E402

PLATE = """
[campaign]
name = "bench-plate"
rig = "{rig}"
fs = 32000.0
duration = 3.0

[controller]
kind = "plate-mfc"
gamma = 1.0
k_p = 5000.0
k_d = 195.0

[differentiator]
alpha = 4
beta = 4
omega_c = 840.0

[reference]
kind = "lift"
"""

MOTOR = """
[campaign]
name = "bench-motor"
rig = "{rig}"
fs = 1000.0
duration = 5.0

[controller]
kind = "mfc2"
output = "angle"
gamma = 108.55
k_p = 400.0
k_d = 40.0

[differentiator]
alpha = 9
beta = 9
omega_c = 200.0
method = "analytic"

[reference]
kind = "setpoints"
levels = [0.0, 6.283185307179586, 0.0]
transition = 1.0
hold = 1.5
"""

CASES = {
    "plate-can": ("plate-can.toml", PLATE),
    "plate-serial": ("plate-serial.toml", PLATE),
    "motor-can": ("dcmotor-can.toml", MOTOR),
}


def _local_rig(name: str, directory: Path) -> Path:
    """The shipped rig file on a loopback bus (udp_multicast) with its loop on the device."""
    text = (ROOT / "rigs" / name).read_text()
    port = random.randint(20000, 60000)
    text = text.replace('interface = "socketcan"', 'interface = "udp_multicast"')
    text = text.replace('channel = "can0"', f'channel = "239.74.163.2"\nport = {port}')
    text = text.replace('loop = "host"', 'loop = "device"')
    path = directory / name
    path.write_text(text)
    return path


def run_case(case: str) -> None:
    rig_name, campaign = CASES[case]
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        rig_path = _local_rig(rig_name, tmp_path)
        emulator = subprocess.Popen(
            [sys.executable, "-m", "labrunner", "emulate", str(rig_path), "--free-run"],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        try:
            line = emulator.stdout.readline().strip()
            if line.startswith("port "):
                rig_path.write_text(rig_path.read_text().replace('port = "/dev/ttyACM0"', f'port = "{line[5:]}"'))
                emulator.stdout.readline()
            (tmp_path / "campaign.toml").write_text(campaign.format(rig=rig_path.name))
            t0 = time.perf_counter()
            done = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "labrunner",
                    "run",
                    str(tmp_path / "campaign.toml"),
                    "--out",
                    str(tmp_path / "out"),
                ],
                capture_output=True,
                text=True,
                cwd=ROOT,
            )
            wall = time.perf_counter() - t0
        finally:
            emulator.send_signal(signal.SIGINT)
            emulator.wait(timeout=10)
        if done.returncode:
            print(f"{case}: labrunner run failed: {done.stderr.strip()}")
            return
        [log_path] = (tmp_path / "out" / "runs").glob("*.mcap")
        log = read_run(str(log_path))
        d = log.metadata["diagnostics"]
        dl = d["device_loop"]
        config = load_rig_config(str(rig_path))
        link = linkload.from_rig(config.kind, config.parameters)
        fs = float(log.metadata["config"]["campaign"]["fs"])
        moved = dl["bytes_to_device"] + dl["bytes_to_host"]
        print(f"{case}: {dl['ticks']} ticks at {fs:g} Hz, outcome {log.outcome['status']}")
        print(f"  labrunner run → MCAP published: {wall:.1f} s wall (Python start-up, plan and publish included)")
        print(
            f"  device compute {dl['device_compute_s']:.2f} s for {dl['device_run_s']:.2f} s of device time; "
            f"description sent and checked in {dl['accept_s'] * 1e3:.0f} ms; ACCEPT → VERDICT {dl['run_s']:.1f} s"
        )
        print(
            f"  moved: {dl['bytes_to_device']} B to the device, {dl['bytes_to_host']} B to the host "
            f"({moved / 1e6:.2f} MB; {d['link']['received']} frames received, {dl['blocks_resent']} host blocks resent, "
            f"receiver {dl['received']})"
        )
        print(
            f"  on {linkload.describe(link)} the samples alone take ≈ "
            f"{linkload.bulk_bytes_s(link, dl['bytes_to_host']):.1f} s after the run (streamed during it: {dl['streamed']})"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=sorted(CASES))
    args = parser.parse_args()
    print("machine: 2 cores shared with other jobs; wall times, not CPU times (two processes talk)")
    for case in [args.only] if args.only else list(CASES):
        run_case(case)


if __name__ == "__main__":
    main()
