"""Issue 36: select()'s conditions either match correctly or are refused in one line naming the
column — NaN, infinite and reversed bounds, generators, a slice's step, numpy arrays, ranges —
and friction 3: near() matches the grid value nearest a number (as xarray's
``sel(method="nearest")``), and a number on no grid value says which is closest."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from test_campaign_support import campaign_text, write

from labrunner.cli import main
from labrunner.errors import InvalidParameter
from labrunner.results import near, open_campaign
from labrunner.results.conditions import mask

GRID = np.logspace(0.0, 1.0, 4)  # 1, 2.1544…, 4.6416…, 10: what the report prints as 2.154 and 4.642
COLUMN = pd.Series(np.repeat(GRID, 2), name="controller.k_p")  # two rows per value


def rows(m: np.ndarray) -> list[int]:
    return np.flatnonzero(m).tolist()


def match(wanted, grid: bool = True) -> list[int]:
    return rows(mask("controller.k_p", COLUMN, wanted, grid=grid))


def test_values_in_any_iterable_match_the_same_rows():
    expected = [0, 1, 6, 7]
    assert match([1.0, 10.0]) == expected
    assert match((1.0, 10.0)) == expected
    assert match({1.0, 10.0}) == expected
    assert match(np.array([1.0, 10.0])) == expected
    assert match(v for v in (1.0, 10.0)) == expected  # a generator, consumed once
    assert match(range(1, 11, 9)) == expected  # 1 and 10
    assert match(np.float64(10.0)) == [6, 7] and match(np.array(10.0)) == [6, 7]


def test_ranges_are_closed_and_open_where_none_or_infinite():
    assert match(slice(2.0, 5.0)) == [2, 3, 4, 5]
    assert match(slice(None, 2.0)) == [0, 1]
    assert match(slice(-math.inf, math.inf)) == list(range(8))
    assert match(slice(GRID[1], GRID[1])) == [2, 3]


@pytest.mark.parametrize(
    "wanted, says",
    [
        (slice(math.nan, 5.0), "ends must be numbers"),
        (slice(1.0, math.nan), "ends must be numbers"),
        (slice(5.0, 1.0), "the range is reversed"),
        (slice(1.0, 10.0, 2), "a slice's step is not supported"),
        (slice("a", 2.0), "ends must be numbers"),
        (math.nan, "NaN equals no value"),
        ([1.0, math.nan], "NaN equals no value"),
        ([], "an empty list"),
        (None, "None equals no value"),
        ({"a": 1}, "a mapping is no condition"),
        (lambda c: c > 1, None),  # fine: a boolean mask
        (lambda c: 3, "a callable must return one boolean per row"),
    ],
)
def test_what_would_match_silently_wrong_is_refused_in_one_line(wanted, says):
    if says is None:
        assert match(wanted) == [2, 3, 4, 5, 6, 7]
        return
    with pytest.raises(InvalidParameter, match=says) as err:
        match(wanted)
    assert err.value.field == "controller.k_p" and "\n" not in str(err.value)


def test_a_number_on_no_grid_value_names_the_closest():
    with pytest.raises(InvalidParameter) as err:
        match(2.154)
    assert f"no grid value near 2.154; closest {float(GRID[1])!r}" in str(err.value)
    assert match(2.154, grid=False) == []  # a metric column: no grid to be on, 0 rows
    with pytest.raises(InvalidParameter, match="no grid value near inf"):
        match(math.inf)


def test_near_matches_the_nearest_grid_value_within_its_tolerance():
    assert match(near(2.154)) == [2, 3]
    assert match(near(4.642)) == [4, 5]
    assert match(near(1e9)) == [6, 7]
    assert match(near(2.154, 1e-3)) == [2, 3]
    with pytest.raises(InvalidParameter, match=f"no grid value within 0.0001 of 2.154; closest {float(GRID[1])!r}"):
        match(near(2.154, 1e-4))
    for bad in (math.nan, math.inf, "2"):
        with pytest.raises(InvalidParameter, match="near"):
            near(bad)
    with pytest.raises(InvalidParameter, match="tolerance must be a finite number >= 0"):
        near(2.0, -1.0)


def test_select_on_a_campaign(project):
    grid = '"controller.k_p" = { log10 = [0.0, 1.0], num = 4 }'
    path = write(project / "sel.toml", campaign_text("sel", grid=grid, duration=0.5))
    assert main(["run", str(path), "--workers", "1"]) == 0
    campaign = open_campaign(project / "data" / "sel")
    table = campaign.table()
    k_p = sorted(table["controller.k_p"])
    assert campaign.select(k_p=near(2.154))["id"].tolist() == table[table["controller.k_p"] == k_p[1]]["id"].tolist()
    with pytest.raises(InvalidParameter, match=r"no grid value near 2\.154; closest 2\.15443"):
        campaign.select(k_p=2.154)
    assert len(campaign.select(k_p=range(1, 11, 9))) == 2
    assert len(campaign.select(k_p=np.array(k_p[:2]))) == 2
    assert len(campaign.select(k_p=slice(2.0, None), outcome="no such outcome")) == 0  # a string column: 0 rows
    with pytest.raises(InvalidParameter, match="where: must map column names"):
        campaign.select(["k_p"])


def test_vectors_refuses_an_empty_out(project, capsys):
    assert main(["vectors", "--out", ""]) == 2
    assert "--out: must be a path" in capsys.readouterr().err
    assert sorted(p.name for p in project.iterdir()) == ["pyproject.toml", "rigs"]
