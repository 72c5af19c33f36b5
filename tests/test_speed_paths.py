"""Optimised paths against their plain references (issue 14)."""

from __future__ import annotations

import copy
import datetime

from labrunner.campaign.spec import copy_tree


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
