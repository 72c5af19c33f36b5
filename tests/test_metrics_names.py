"""A run cut short has one name for its metrics everywhere (issue 36): an aborted run's RMS was
``rms_error`` in ``run.metrics`` and ``inspect`` but ``rms_error_until_abort`` in the table, and a
failed run cut short at 727 of 1000 samples still filled ``rms_error`` and could rank."""

from __future__ import annotations

import json
import math

import numpy as np
from test_campaign_support import MOTOR_RIG, campaign_text, write

from labrunner import open_campaign
from labrunner.cli import main
from labrunner.metrics import as_reported
from labrunner.rigs.registry import register_rig
from labrunner.rigs.sim.dcmotor import DCMotorTwin

FAIL_AT = 150  # ticks: 0.75 s of a 2 s run


class FlakyMotor(DCMotorTwin):
    """The motor twin whose simulation breaks after :data:`FAIL_AT` ticks (an exception, not the plant)."""

    KIND = "flaky-motor"

    def _step(self, u):
        if self.k >= FAIL_AT:
            raise ArithmeticError("the twin broke")
        return super()._step(u)


def test_as_reported_renames_only_the_ranked_metrics_of_a_run_cut_short():
    metrics = {"rms_error": 1.0, "rms_e_omega@hold": 2.0, "input_energy": 3.0, "n_samples": 40, "oscillating": 0.0}
    assert as_reported(metrics, "completed") == metrics
    assert as_reported(metrics, "failed") == {
        "rms_error_until_abort": 1.0,
        "rms_e_omega@hold_until_abort": 2.0,
        "input_energy_until_abort": 3.0,
        "n_samples": 40,
        "oscillating": 0.0,
    }


def test_aborted_and_failed_runs_name_their_metrics_as_the_table_does(project, capsys):
    register_rig(FlakyMotor.KIND, FlakyMotor)  # the pool's workers are forked: they see it too
    write(project / "rigs" / "flaky.toml", MOTOR_RIG.replace('kind = "dcmotor"', 'kind = "flaky-motor"'))
    grid = '"controller.k_p" = { values = [10.0, 3000.0] }'  # k_p = 3000 1/s trips the |du/dt| limit
    assert main(["run", str(write(project / "a.toml", campaign_text(name="a", grid=grid))), "--workers", "1"]) == 0
    flaky = campaign_text(name="f", rig="rigs/flaky.toml", grid='"controller.k_p" = { values = [10.0] }')
    assert main(["run", str(write(project / "f.toml", flaky)), "--workers", "1"]) == 0
    rows = {}
    for name in ("a", "f"):
        campaign = open_campaign(project / "data" / name)
        for _, row in campaign.table().iterrows():
            rows[row["outcome"]] = (campaign, row)
    assert set(rows) == {"completed", "aborted", "failed"}
    for outcome, (campaign, row) in rows.items():
        run = campaign.run(row["id"])
        cut = outcome != "completed"
        name = "rms_error_until_abort" if cut else "rms_error"
        assert math.isnan(row["rms_error" if cut else "rms_error_until_abort"])  # only whole runs rank
        assert run.metrics[name] == row[name]
        assert ("rms_error" in run.metrics) is not cut
        capsys.readouterr()
        assert main(["inspect", str(run.path)]) == 0
        assert f"{name}={row[name]}" in capsys.readouterr().out
        assert main(["inspect", str(run.path), "--json"]) == 0
        shown = json.loads(capsys.readouterr().out)["metadata"]["metrics"]
        assert shown[name] == row[name] and ("rms_error" in shown) is not cut
    failed = rows["failed"][1]
    assert failed["n_samples"] == FAIL_AT + 1 and np.isfinite(failed["rms_error_until_abort"])  # cut short, measured
