"""Instructions per tick of each control law on the Cortex-M4F image of firmware/, counted by QEMU.

Builds ``make -C firmware m4`` (arm-none-eabi-gcc, -mcpu=cortex-m4 -mfpu=fpv4-sp-d16
-mfloat-abi=hard), then runs its semihosting benchmark in ``qemu-system-arm -M mps2-an386
-icount shift=0`` on every vector of docs/vectors/ (the sensor-table mode: the law, the
reference, saturation and the safety routine of one tick). With ``-icount shift=0`` one
instruction takes 1 ns of virtual time, so the 25 MHz timer counts instructions (40 a count).
An estimate: a Cortex-M4F takes at least one cycle an instruction, more for loads, FPU
multiply-accumulates and flash wait states; the budget column is a 168 MHz part's cycles per
period at the vector's f_s, and "fits" compares it with the instruction count (a lower bound).
Also prints the images' text/data/bss (arm-none-eabi-size).

    python benchmarks/bench_firmware_m4.py [--arith f32 f64] [--cases NAME ...]
"""

from __future__ import annotations

import argparse
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLOCK_HZ = 168e6


def build(out: Path) -> str:
    """``make m4`` into ``out``; the size table it prints."""
    done = subprocess.run(
        ["make", "-s", "-C", str(ROOT / "firmware"), "m4", f"BUILD={out}"], capture_output=True, text=True, check=True
    )
    return done.stdout


def bench(image: Path, cases: list[str], timeout: float = 600) -> list[str]:
    """The benchmark's lines (one per case) from QEMU."""
    arg = " ".join(["bench", *(str(Path("docs/vectors") / c) for c in cases)])
    done = subprocess.run(
        ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none",
         "-icount", "shift=0", "-semihosting-config", f"enable=on,target=native,arg={arg}", "-kernel", str(image)],
        capture_output=True, text=True, cwd=ROOT, timeout=timeout,
    )  # fmt: skip
    if done.returncode != 0:
        raise SystemExit(f"bench_firmware_m4: QEMU exited {done.returncode}: {done.stderr.strip()}")
    return done.stderr.splitlines()  # QEMU writes the semihosting console to stderr


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arith", nargs="+", default=["f32", "f64"], choices=["f32", "f64"])
    parser.add_argument("--cases", nargs="+", default=sorted(p.name for p in (ROOT / "docs" / "vectors").iterdir()))
    parser.add_argument("--build", type=Path, default=ROOT / "firmware" / "build")
    args = parser.parse_args()
    sizes = build(args.build)
    print(sizes.strip())
    print(f"\n{'case':<28} {'arith':<7} {'insn/tick':>9} {'max':>7} {'f_s':>7} {'budget':>7}  fits 168 MHz")
    for arith in args.arith:
        for line in bench(args.build / "m4" / f"bench-{arith}.elf", args.cases):
            m = re.match(
                r"(\S+)\s+(float\d\d)\s+(\d+) insn/tick \(max (\d+)\) over \d+ ticks, FIR \d+ taps, f_s (\d+)", line
            )
            if m is None:
                print(line)
                continue
            name, kind, mean, worst, fs = m.group(1), m.group(2), int(m.group(3)), int(m.group(4)), int(m.group(5))
            budget = CLOCK_HZ / fs
            verdict = "yes" if worst <= budget else f"no ({worst / budget:.1f}x)"
            print(f"{name:<28} {kind:<7} {mean:>9} {worst:>7} {fs:>7} {budget:>7.0f}  {verdict}")


if __name__ == "__main__":
    main()
