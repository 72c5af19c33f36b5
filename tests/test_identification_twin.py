"""`labrunner identify` on the simulated DC motor (thesis Sec. 3.2 experiments, campaigns/dcmotor-identification.toml):
recovers a and b within 2 % on the frictionless twin; on the default twin, calibrated for friction, the thesis's
procedure returns the thesis's a and b within 3 % and ``--friction`` the twin's physical values."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from labrunner import engine
from labrunner.campaign import spec
from labrunner.cli import main
from labrunner.identification import identify_logs, identify_signals, nominal_constants
from labrunner.logs import write_run
from labrunner.rigs import registry

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = ROOT / "campaigns" / "dcmotor-identification.toml"
A, B = 39.44, 108.55  # rigs/dcmotor-*.toml, thesis Sec. 3.2


def _run_on(rig_name: str, directory: Path) -> list[Path]:
    """The campaign's four step experiments on ``rig_name``, logged like a campaign worker does."""
    campaign = spec.load(CAMPAIGN)
    assert campaign.fs == 100.0 and campaign.rig_info.kind == "dcmotor"  # thesis Sec. 3.2: 100 Hz, open loop
    points = [config for _, config in campaign.points()]
    assert all(p["controller"]["kind"] == "open-loop" for p in points)
    with registry.load_rig(rig_name, search=[ROOT / "rigs"]) as rig:
        results = engine.run_batch(
            points,
            rig,
            fs=campaign.fs,
            duration=campaign.duration,
            seeds=[0] * len(points),
            rig_safety=campaign.rig_safety,
        )
    paths = []
    for i, (point, result) in enumerate(zip(points, results)):
        assert result.outcome.status == "completed"
        path = directory / f"step{i}.mcap"
        write_run(
            path,
            metadata={"run": {"rig": rig_name}, "config": point},
            fs=result.fs,
            signals=result.signals,
            outcome=result.outcome.as_dict(),
            channels=result.channels,
        )
        paths.append(path)
    return paths


def test_frictionless_twin_recovers_a_and_b_within_2_percent(tmp_path):
    paths = _run_on("dcmotor-frictionless", tmp_path)
    result = identify_logs(paths, nominal=nominal_constants(paths[0], search=[ROOT / "rigs"]))
    assert result["a"] == pytest.approx(A, rel=0.02)
    assert result["b"] == pytest.approx(B, rel=0.02)
    assert len(result["per_run"]) == 4
    assert sorted(r["u_final"] for r in result["per_run"]) == [-12.0, -6.0, 6.0, 12.0]
    for run in result["per_run"]:
        assert run["a"] == pytest.approx(A, rel=0.02) and run["b"] == pytest.approx(B, rel=0.02)
    assert result["nominal"] == {"a": A, "b": B}
    assert abs(result["bias"]["a"]) < 0.02 and abs(result["bias"]["b"]) < 0.02


def test_calibrated_twin_identification_within_3_percent_of_the_thesis(tmp_path, monkeypatch):
    """End to end: run the campaign file on the default (calibrated) twin, identify from its
    directory. Friction (Coulomb 0.6 V) acts like a smaller input, b_eff ≈ b·(1 − 0.6 V/|u|); the twin's
    physical b = 121.3, a = 40.8 are chosen so that the thesis's procedure returns its 39.44 / 108.55."""
    monkeypatch.chdir(ROOT)
    out = tmp_path / "ident"
    assert main(["run", str(CAMPAIGN), "--out", str(out), "--workers", "1"]) == 0
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "identify", str(out), "--json", "--friction"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )  # the real command, end to end
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert len(result["per_run"]) == 4
    assert result["nominal"] == {"a": A, "b": B}  # the rig's constants: the thesis's identified values
    assert result["a"] == pytest.approx(A, rel=0.03) and result["b"] == pytest.approx(B, rel=0.03)
    by_level = {abs(r["u_final"]): [] for r in result["per_run"]}
    for r in result["per_run"]:
        by_level[abs(r["u_final"])].append(r["b"])
    assert max(by_level[6.0]) < min(by_level[12.0])  # the friction bias shrinks with the step height
    # the pooled friction fit sees through the Coulomb term to the twin's physical values
    physical, fit = result["physical"], result["friction"]
    assert physical == {"a": 40.8, "b": 121.3, "coulomb": 0.6}
    assert fit["coulomb"] == pytest.approx(0.6, rel=0.1)
    assert fit["b"] == pytest.approx(121.3, rel=0.06) and fit["a"] == pytest.approx(40.8, rel=0.06)
    assert abs(fit["b"] / 121.3 - 1) < abs(result["b"] / 121.3 - 1)  # closer than the frictionless model


def test_calibration_holds_over_noise_seeds(tmp_path):
    """The calibration is not one lucky noise draw: seeds 1-3 also land within 3 %."""
    campaign = spec.load(CAMPAIGN)
    points = [config for _, config in campaign.points()]
    with registry.load_rig("dcmotor-sim", search=[ROOT / "rigs"]) as rig:
        for seed in (1, 2, 3):
            results = engine.run_batch(
                points,
                rig,
                fs=campaign.fs,
                duration=campaign.duration,
                seeds=[seed] * len(points),
                rig_safety=campaign.rig_safety,
            )
            est = [identify_signals(r.signals["theta"], r.signals["u"], r.fs) for r in results]
            assert sum(e.a for e in est) / 4 == pytest.approx(A, rel=0.03)
            assert sum(e.b for e in est) / 4 == pytest.approx(B, rel=0.03)
