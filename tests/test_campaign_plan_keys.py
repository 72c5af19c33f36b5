"""The planner's batch keys (found once per shape of a point's parameters, without resolving each
point twice: issue 36's planning cost) equal the plain per-point ones: every point's configuration
resolved and walked, for shipped grids with string, boolean and list axes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from labrunner.campaign import spec
from labrunner.campaign.checks import StaticChecker, batch_key

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    "name",
    [
        "quickstart.toml",
        "dcmotor-identification.toml",  # a list axis (reference.levels)
        "dcmotor-velocity-omegac-alpha.toml",
        "valve-paper/fig07-parametrisations.toml",  # string axes
        "plate-paper/fig08-input-gains.toml",
        "thesis/fig3-11-constant-ratio.toml",  # derived gains
    ],
)
def test_batch_keys_equal_the_plain_per_point_keys(name):
    campaign = spec.load(ROOT / "campaigns" / name)
    points, _ = spec.plan(campaign)
    checker = StaticChecker(campaign.rig_config)  # the split keys the planner discovered, found again
    for seq, (params, config) in enumerate(campaign.points()):
        list(checker.add(seq, params, config))
    list(checker.flush())
    for point in points:
        config = campaign.resolve(point.parameters)
        config["campaign"]["duration"] = json.loads(point.batch_key)[2]
        assert point.batch_key == batch_key(campaign.rig, config, checker.split), point.id
