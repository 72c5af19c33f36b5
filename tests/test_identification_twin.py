"""`labrunner identify` on the simulated DC motor (thesis Sec. 3.2 experiments, campaigns/dcmotor-identification.toml):
recovers a and b within 2 % on the frictionless twin and reports the bias of friction on the default twin."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from labrunner import engine
from labrunner.campaign import spec
from labrunner.cli import main
from labrunner.identification import identify_logs, nominal_constants
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
        results = engine.run_batch(points, rig, fs=campaign.fs, duration=campaign.duration, seeds=[0] * len(points),
                                   rig_safety=campaign.rig_safety)
    paths = []
    for i, (point, result) in enumerate(zip(points, results)):
        assert result.outcome.status == "completed"
        path = directory / f"step{i}.mcap"
        write_run(path, metadata={"run": {"rig": rig_name}, "config": point}, fs=result.fs, signals=result.signals,
                  outcome=result.outcome.as_dict(), channels=result.channels)
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


def test_default_twin_campaign_and_cli_report_the_friction_bias(tmp_path, monkeypatch):
    """End to end: run the campaign file, identify from its directory. Coulomb friction (0.6 V) acts
    like a smaller input, b_eff ≈ b·(1 − 0.6 V/|u|), so b comes out several per cent low."""
    monkeypatch.chdir(ROOT)
    out = tmp_path / "ident"
    assert main(["run", str(CAMPAIGN), "--out", str(out), "--workers", "1"]) == 0
    done = subprocess.run([sys.executable, "-m", "labrunner", "identify", str(out), "--json"], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)  # the real command, end to end
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert len(result["per_run"]) == 4
    assert result["nominal"] == {"a": A, "b": B}
    assert -0.25 < result["bias"]["b"] < -0.03  # friction lowers the effective input gain
    assert abs(result["bias"]["a"]) < 0.10
    by_level = {abs(r["u_final"]): [] for r in result["per_run"]}
    for r in result["per_run"]:
        by_level[abs(r["u_final"])].append(r["b"])
    assert max(by_level[6.0]) < min(by_level[12.0])  # the bias shrinks with the step height
