"""Optimised paths against their plain references (issue 14)."""

from __future__ import annotations

import copy
import datetime
import os
import subprocess
import sys
from pathlib import Path

from labrunner.campaign.config_tree import copy_tree


def test_copy_tree_is_deepcopy_of_toml_data():
    data = {
        "a": 1,
        "b": [1.5, {"c": "x", "d": [True, None]}],
        "e": {"f": {"g": [[1, 2], [3]]}},
        "t": datetime.date(2026, 1, 2),
        "h": (1, [2]),
    }
    copied = copy_tree(data)
    assert copied == copy.deepcopy(data)
    copied["b"][1]["d"].append(1)
    copied["e"]["f"]["g"][0][0] = 9
    copied["h"][1].append(3)
    assert data["b"][1]["d"] == [True, None] and data["e"]["f"]["g"][0][0] == 1 and data["h"] == (1, [2])


_BATCH_DIGEST = """
import hashlib, pathlib, numpy as np
from labrunner import engine
from labrunner.campaign import spec
from labrunner.rigs.registry import load_rig
c = spec.load(pathlib.Path({root!r}) / "campaigns" / "quickstart.toml")
points, _ = spec.plan(c)
configs = [c.resolve(p.parameters) for p in points[:64]]  # ≥ 32 runs share one differentiator: BLAS sums the taps
with load_rig(c.rig_ref, search=c.rig_search) as rig:
    results = engine.run_batch(configs, rig, fs=c.fs, duration=1.0, seeds=[c.seed] * 64, rig_safety=c.rig_safety)
digest = hashlib.sha256()
for r in results:
    for name, values in r.signals.items():
        digest.update(name.encode() + np.ascontiguousarray(values).tobytes())
print(digest.hexdigest())
"""


def test_one_blas_thread_gives_the_same_runs_bit_for_bit():
    """``run``/``resume`` give numpy's OpenBLAS one thread (labrunner.cli.run_cmd.one_blas_thread):
    a lockstep batch's runs are the same bits as with the library's default threads."""
    root = Path(__file__).resolve().parents[1]
    code = _BATCH_DIGEST.format(root=str(root))
    digests = set()
    for threads in ("1", "2", None):
        env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
        if threads:
            env["OPENBLAS_NUM_THREADS"] = threads
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
        digests.add(out.stdout.strip())
    assert len(digests) == 1
