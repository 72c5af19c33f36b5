"""Run-log size (issue 26): the disk each shipped twin campaign's logs take at ``[logging]
precision`` float64 (the default: every value exact) and float32 (every value rounded), the
median log of a completed run of each, and, for one completed 5 s motor run, the floors that
bound any log holding one plottable MCAP message per sample.

    nice -n 10 python benchmarks/bench_log_size.py [--work DIR] [--only quickstart]

Each campaign is run twice with ``labrunner run`` (fresh processes) into ``--work`` (default a
temporary folder; the plate needs ~2.3 GB), then deleted.

The floors: the MCAP message records' 31-byte headers (opcode, length, channel, sequence, log and
publish time) of 1000 messages alone, zstd-compressed at level 19; the run's values, column by
column, byte-shuffled after a delta of their bit patterns and zstd-compressed at level 19 (better
than any per-sample layout can do, since per-sample messages interleave the columns).

Last measured 2026-12-03 (2-core machine, other jobs running; sizes do not depend on load)::

    campaign        logs    f64 logs    f32 logs    completed run f64 / f32 (median)
    quickstart       100       2.8MB       2.0MB                   48.6 kB / 32.4 kB
    valve             64     293.3MB     174.6MB               4757.9 kB / 2752.3 kB
    plate             70    1538.2MB     922.5MB             23296.8 kB / 14058.0 kB

    floors for the largest quickstart log (1000 samples, 52.4 kB): message headers 6.2 kB;
    values float64 27.7 kB, float32 12.0 kB (each column alone, shuffled, zstd -19); so one
    message per sample needs ≥ 33.9 kB exact, ≥ 18.2 kB in float32, before metadata (≈ 6 kB)

and (2026-12-03 11:00, the same log's floors computed alone): metadata 6.5 kB; the whole run as
one message of packed arrays 32.6 kB float64, 16.0 kB float32 (zstd -19).

2026-12-04 15:05 UTC, format labrunner-4 (every chunk with its message indexes, which
@mcap/core's indexed reader — Foxglove's — requires: 16 uncompressed bytes a sample)::

    quickstart       100       3.7MB       2.9MB                   64.8 kB / 48.5 kB

    floors for the largest quickstart log (1000 samples, 68.7 kB): ... before message indexes
    (16.0 kB in this log) and metadata (6.6 kB)

so the indexes cost +16.0 kB a 1000-sample motor run (+33 % at float64, +50 % at float32). The
valve and plate campaigns were not rerun (minutes and 2.3 GB); their runs grow by the same 16 B
a sample: +1.6 MB a 25 s valve run at 4 kHz, +2.0 MB a 4 s plate run at 32 kHz (computed).

A motor log of 1000 samples at ≤ 20 kB (the issue's target) is out of reach with one message per
sample, and exact (float64) in any layout a third-party MCAP reader can decompress: ≥ 33.9 kB
per sample, ≥ 39 kB (32.6 + 6.5) as one message of arrays. Only float32 as one message of
arrays (≈ 22.5 kB with today's metadata) comes near it, and gives up Foxglove's plot over time.
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import zstandard

ROOT = Path(__file__).resolve().parent.parent
CAMPAIGNS = {
    "quickstart": "campaigns/quickstart.toml",
    "valve": "campaigns/valve-gamma-kp.toml",
    "plate": "campaigns/plate-alpha-omegac.toml",
}
_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("ch", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")])


def with_precision(text: str, precision: str) -> str:
    """The campaign file with ``[logging] precision`` set (added to its ``[logging]`` or appended)."""
    if re.search(r"^\[logging\]", text, re.MULTILINE):
        return re.sub(r"^\[logging\]\n", f'[logging]\nprecision = "{precision}"\n', text, flags=re.MULTILINE)
    return f'{text}\n[logging]\nprecision = "{precision}"\n'


def run_campaign(source: Path, precision: str, work: Path) -> Path:
    """Run the campaign at ``precision`` with the CLI; return its directory."""
    path = work / f"{source.stem}-{precision}.toml"
    path.write_text(with_precision(source.read_text(), precision))
    out = work / f"{source.stem}-{precision}"
    cmd = [sys.executable, "-m", "labrunner", "run", str(path), "--out", str(out)]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True)
    return out


def sizes(directory: Path) -> tuple[int, int, list[int]]:
    """(bytes of all logs, their number, sizes of the completed runs' logs)."""
    import labrunner

    table = labrunner.open_campaign(directory).table()
    logs = list((directory / "runs").glob("*.mcap"))
    completed = [Path(p).stat().st_size for p in table.loc[table["outcome"] == "completed", "log_path"]]
    return sum(p.stat().st_size for p in logs), len(logs), completed


def floors(log: Path) -> dict[str, int]:
    """Compressed bytes of the message headers alone and of the values column by column at their
    best (see the module's docstring), for one run's log."""
    import labrunner

    run = labrunner.open_run(log)
    values = run.signals.to_numpy()
    n = len(values)
    headers = np.zeros(n, _HEADER)
    headers["op"], headers["len"], headers["ch"], headers["seq"] = 5, 22 + 9 * values.shape[1], 1, np.arange(n)
    headers["log"] = headers["pub"] = 1_796_281_482_043_603_200 + 5_000_000 * np.arange(n, dtype=np.uint64)
    zstd = zstandard.ZstdCompressor(level=19)
    out = {"samples": n, "headers": len(zstd.compress(headers.tobytes()))}
    for dtype, key in ((np.float64, "values_f64"), (np.float32, "values_f32")):
        total = 0
        for column in values.T.astype(dtype):
            as_int = column.view(np.int64 if dtype == np.float64 else np.int32)
            delta = np.diff(as_int, prepend=as_int[:1] * 0)
            shuffled = delta.view(np.uint8).reshape(n, -1).T.copy()
            total += len(zstd.compress(shuffled.tobytes()))
        out[key] = total
        # the whole run as one message of packed arrays (column after column, as protobuf lays out
        # repeated fields): no per-sample header, but only what zstd alone makes of the values,
        # since a third-party reader can undo no shuffle
        out[f"one_message_{key[-3:]}"] = len(zstd.compress(values.T.astype(dtype).tobytes()))
    out["indexes"] = _record_bytes(log, 0x07)
    out["metadata"] = log.stat().st_size - _record_bytes(log, 0x06) - out["indexes"]
    return out


def _record_bytes(log: Path, opcode: int) -> int:
    """Bytes of the log's records of ``opcode`` in its data section: chunks (0x06, the compressed
    samples) or message indexes (0x07, 16 bytes a message, uncompressed, which Foxglove's indexed
    reader needs); the rest is metadata, schemas, channels, the attachment and the summary."""
    data, offset, total = log.read_bytes(), 8, 0
    while offset < len(data) - 8:
        length = 9 + int.from_bytes(data[offset + 1 : offset + 9], "little")
        total += length if data[offset] == opcode else 0
        offset += length
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=None, help="where the campaigns go (deleted after)")
    parser.add_argument("--only", nargs="*", choices=sorted(CAMPAIGNS), default=sorted(CAMPAIGNS))
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="logsize-", dir=args.work))
    print(f"{'campaign':<12}{'logs':>8}{'f64 logs':>12}{'f32 logs':>12}{'completed run f64 / f32 (median)':>36}")
    try:
        for name in [n for n in CAMPAIGNS if n in args.only]:
            source = ROOT / CAMPAIGNS[name]
            figures = {}
            for precision in ("float64", "float32"):
                directory = run_campaign(source, precision, work)
                figures[precision] = sizes(directory)
                if name == "quickstart" and precision == "float64":
                    table_logs = sorted((directory / "runs").glob("*.mcap"), key=lambda p: p.stat().st_size)
                    motor_floor = floors(table_logs[-1])
                    motor_size = table_logs[-1].stat().st_size
                shutil.rmtree(directory)
            (t64, n, c64), (t32, _, c32) = figures["float64"], figures["float32"]
            med = f"{statistics.median(c64) / 1e3:.1f} kB / {statistics.median(c32) / 1e3:.1f} kB" if c64 else "none"
            print(f"{name:<12}{n:>8}{t64 / 1e6:>10.1f}MB{t32 / 1e6:>10.1f}MB{med:>36}", flush=True)
        if "quickstart" in args.only:
            f = motor_floor
            print(
                f"\nfloors for the largest quickstart log ({f['samples']} samples, {motor_size / 1e3:.1f} kB): "
                f"message headers {f['headers'] / 1e3:.1f} kB; values float64 {f['values_f64'] / 1e3:.1f} kB, "
                f"float32 {f['values_f32'] / 1e3:.1f} kB (each column alone, shuffled, zstd -19); "
                f"so one message per sample needs ≥ {(f['headers'] + f['values_f64']) / 1e3:.1f} kB exact, "
                f"≥ {(f['headers'] + f['values_f32']) / 1e3:.1f} kB in float32, before message indexes "
                f"({f['indexes'] / 1e3:.1f} kB in this log) and metadata "
                f"({f['metadata'] / 1e3:.1f} kB); the whole run as one message of arrays "
                f"(no per-sample plot over time) {f['one_message_f64'] / 1e3:.1f} kB float64, "
                f"{f['one_message_f32'] / 1e3:.1f} kB float32 (zstd -19), before metadata"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
