"""benchmarks/naive_reference.py (the per-sample closed loops bench_campaign.py compares the
engine with), importable by the tests that check the engine and the motor twin against it."""

import importlib.util
from pathlib import Path

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "naive_reference.py"
_spec = importlib.util.spec_from_file_location("benchmarks_naive_reference", _PATH)
naive = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(naive)
