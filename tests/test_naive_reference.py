"""The naive per-sample script of benchmarks/naive_reference.py computes the engine's closed loops,
so that bench_campaign.py's speed ratio compares like with like (issue 14)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from naive_reference import naive

from labrunner import engine
from labrunner.campaign import spec
from labrunner.rigs.registry import load_rig

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("batch", [3, 40])  # the estimator's per-run bank and its shared BLAS path
def test_naive_loops_equal_the_engine_for_completed_and_aborted_points(batch):
    path = ROOT / "campaigns" / "quickstart.toml"
    cfg, gammas, kps = naive.load(path)
    campaign = spec.load(path, root=ROOT)
    chosen = [(gammas[5], kps[3]), (gammas[9], kps[9]), (gammas[2], kps[0])]  # near b, large gains, small γ
    chosen = (chosen * batch)[:batch]
    points = [campaign.resolve({"controller.gamma": float(g), "controller.k_p": float(k)}) for g, k in chosen]
    rig = load_rig(campaign.rig_ref, search=campaign.rig_search)
    results = engine.run_batch(
        points,
        rig,
        fs=campaign.fs,
        duration=campaign.duration,
        seeds=[campaign.seed] * batch,
        rig_safety=campaign.rig_safety,
    )
    statuses = set()
    for (gamma, k_p), result in zip(chosen[:3], results):
        run = naive.closed_loop(float(gamma), float(k_p), cfg)
        check_naive_style(naive.closed_loop_numpy(float(gamma), float(k_p), cfg), run)
        statuses.add(result.outcome.status)
        assert result.n_samples == run["end"]
        assert (result.outcome.status == "aborted") == run["aborted"]
        np.testing.assert_allclose(result.signals["theta"], run["theta"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(result.signals["omega"], run["omega"], rtol=0, atol=1e-7)
        np.testing.assert_allclose(result.signals["u"], run["u"], rtol=1e-9, atol=1e-9)
    assert statuses == {"completed", "aborted"}


def check_naive_style(numpy_run: dict, floats_run: dict) -> None:
    """The numpy-per-sample script computes the plain-float script's loop (to rounding)."""
    assert numpy_run["end"] == floats_run["end"] and numpy_run["aborted"] == floats_run["aborted"]
    for key in ("theta", "omega", "u"):
        np.testing.assert_allclose(numpy_run[key], floats_run[key], rtol=1e-12, atol=1e-12)
