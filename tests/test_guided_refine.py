"""Boundary refinement on the motor's γ–k_p plane (thesis Sec. 3.5.1, Fig. 3.10) against the full grid."""

from __future__ import annotations

from pathlib import Path

import pytest

from labrunner.campaign import guided, guided_run, spec
from labrunner.campaign.guided_refine import Refine, boundary_cells, mixed

ROOT = Path(__file__).resolve().parents[1]


def test_refinement_of_a_straight_boundary_by_hand():
    # 3 × 3 coarse (stride 4 on a 9 × 9 lattice), outcome changes at x = 4.5: the coarse cells with
    # x-range [4, 8] are mixed (2 of 4), then at each level those whose x-range holds 4.5
    x = spec.gridmod.parse_axis("x", "controller.gamma", {"linspace": [0.0, 8.0], "num": 9})
    y = spec.gridmod.parse_axis("y", "controller.k_p", {"linspace": [0.0, 8.0], "num": 9})
    proc = Refine(x, y, coarse=3, levels=2)
    end = guided.drive(
        proc, "t", lambda pts: [{"status": "aborted" if p["controller.gamma"] > 4.5 else "completed"} for p in pts]
    )
    cells = {tuple(c) for c in end.result.detail["boundary_cells"]}
    assert cells == {(4, j) for j in range(8)}  # the column of cells across x = 4.5, all 8 of them
    # coarse 9 runs; level 1: the two cells [4,8] × [0,4], [4,8] × [4,8] add x = 6 (3 points) and y = 2, 6
    # at x = 4, 6, 8 (6 points): 9; level 2: only the cells [4,6] × … are mixed (4 of them) and add x = 5
    # (9 points) and y = 1, 3, 5, 7 at x = 4, 6 (8 points): 17. In all 35 of 81.
    assert end.result.detail["runs_per_level"] == {"coarse": 9, "level 1": 9, "level 2": 17}
    assert end.runs == 35


def test_mixed_cells_of_a_full_lattice():
    classes = {(i, j): "a" if i + j > 2 else "b" for i in range(3) for j in range(3)}
    assert boundary_cells(classes, 3) == [(0, 1), (1, 0), (1, 1)]
    assert not mixed((0, 0), 1, {(0, 0): "x", (0, 1): "x", (1, 0): "x", (1, 1): "x"})


@pytest.mark.slow
def test_refinement_draws_the_full_grids_boundary_on_the_motor_plane_with_5x_fewer_runs():
    # campaigns/guided/refine-gamma-kp.toml: 9 × 9 coarse, 3 levels → 65 × 65. Outcomes simulated in
    # process with the campaign's own configuration (engine_oracle); the full grid is the reference.
    campaign = spec.load(ROOT / "campaigns" / "guided" / "refine-gamma-kp.toml")
    proc = campaign.guided
    oracle = guided_run.engine_oracle(campaign)
    end = guided.drive(proc, campaign.name, oracle)
    n = proc.size
    # the reference: the same engine, configuration and seeds, in lockstep batches of 256 runs instead
    # of 64 (~2.5x less CPU; runs in a batch are independent: all 4225 outcomes are those of batches of 64)
    full = guided_run.engine_oracle(campaign, batch=256)([proc.point((i, j)) for i in range(n) for j in range(n)])
    classes = {(i, j): full[i * n + j]["status"] for i in range(n) for j in range(n)}
    reference = boundary_cells(classes, n)
    assert {"aborted", "completed", "no-motion"} <= set(classes.values())  # both boundaries of Fig. 3.10
    assert [tuple(c) for c in end.result.detail["boundary_cells"]] == reference
    assert len(reference) > 2 * n  # a real boundary, not a corner
    assert 5 * end.runs <= n * n
    for step in end.walk:  # the refined runs are the full grid's runs
        i, j = (
            proc.x.values.index(step.observation.params[proc.x.key]),
            proc.y.values.index(step.observation.params[proc.y.key]),
        )
        assert step.observation.status == classes[(i, j)]
