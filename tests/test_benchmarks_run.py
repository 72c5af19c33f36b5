"""Every benchmark still runs against the current API (two had silently broken when the engine's
progress hook changed): each is started as a user would, with the smallest arguments it takes,
and must exit 0 and print its figures. The figures themselves are not judged here; the
benchmarks print them against their targets."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

QUICK = {
    "bench_engine.py": (["--batch", "4", "--repeat", "1"], "runs/s per core"),
    "bench_plate.py": (["--batch", "2", "--seconds", "0.1", "--repeat", "1"], "engine.run_batch + safety"),
    "bench_logs.py": (["--repeat", "1", "--motor-runs", "8"], "write"),
    "bench_log_index.py": (["--repeat", "1", "--motor-runs", "4"], "upgrade-logs per log"),
    "bench_startup.py": (["--repeat", "1"], "first batch in the engine"),
    "bench_hostloop.py": (["--seconds", "0.3"], "period"),
    "bench_differentiators.py": ([], ""),
}
SLOW = {
    "bench_analysis.py": (["--sizes", "20", "40"], "fit over"),
    "bench_deviceloop.py": (["--only", "motor-can"], "moved:"),
    "bench_stability.py": (["--size", "5", "--repeat", "10"], "5 x 5 map"),
    "bench_control.py": ([], ""),
    "bench_scale.py": (["--min", "100", "--max", "100", "--synthetic", "400", "--repeat", "1"], "synthetic ledger"),
    "bench_table.py": (["--max", "400", "--repeat", "1"], "per 10^4"),
    "bench_log_size.py": (["--only", "quickstart"], "floors for"),
    "bench_dask_scheduler.py": (["--points", "100"], "bytes a run"),
    "bench_live.py": (["--trials", "1", "--grid", "5", "4"], "one reading, one never reading"),
}


def _run(name: str, args: list[str], expect: str, tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(BENCHMARKS / name), *args], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip(), f"{name} printed no figures"
    assert expect in proc.stdout


@pytest.mark.parametrize("name", QUICK)
def test_a_quick_benchmark_runs(name, tmp_path):
    _run(name, *QUICK[name], tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW)
def test_a_longer_benchmark_runs(name, tmp_path):
    _run(name, *SLOW[name], tmp_path)


def test_every_benchmark_is_run_here_or_timed_by_bench_campaign():
    """A new benchmark gets a line above. Left to be run by hand: bench_rigs (~20 s) and
    bench_campaign (~1 min, the whole-campaign figure); naive_reference has its own test
    (tests/test_naive_reference.py); motor_campaign and synthetic_ledger are helpers the others
    import (bench_scale's run above builds a synthetic ledger)."""
    by_hand = {"bench_campaign.py", "bench_rigs.py", "naive_reference.py", "motor_campaign.py", "synthetic_ledger.py"}
    by_hand.add("bench_firmware_m4.py")  # run on the Cortex-M4 images by tests/test_firmware_m4.py
    assert {p.name for p in BENCHMARKS.glob("*.py")} == set(QUICK) | set(SLOW) | by_hand
