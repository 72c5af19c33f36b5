"""A campaign's free ``[metadata]`` (issue 36: ``[campaign] operator = "me"`` was refused): validated,
kept in the ledger, every log and the results API, searchable across campaigns, and no part of the plan."""

from __future__ import annotations

import json
import sqlite3

import pytest
from test_campaign_support import campaign_text, write

from labrunner import Catalog, open_campaign
from labrunner.campaign import metadata, spec
from labrunner.cli import main
from labrunner.errors import InvalidParameter
from labrunner.logs import read_run

META = """
[metadata]
operator = "Ana"
sample = "motor #3, new brushes"
tags = ["friction", "batch-7"]
repeat = 2
calibrated = 2026-12-01
"""


def test_metadata_values_are_kept_and_bad_ones_named():
    table = {"operator": "Ana", "tags": ["a", "b"], "n": 3, "x": 0.5, "ok": True}
    assert metadata.parse(table) == table
    for bad, field in (
        ({"site": {"room": 1}}, "metadata.site"),  # a nested table
        ({"tags": ["a", ["b"]]}, "metadata.tags[1]"),
        ({"x": float("nan")}, "metadata.x"),
        ({"1st": "a"}, "metadata.1st"),
        ({"notes": "n" * (metadata.MAX_TEXT + 1)}, "metadata.notes"),
    ):
        with pytest.raises(InvalidParameter) as err:
            metadata.parse(bad)
        assert err.value.field == field


def test_an_unknown_campaign_key_points_to_the_metadata_table(project):
    path = write(project / "c.toml", campaign_text().replace("seed = 3", 'seed = 3\noperator = "me"'))
    with pytest.raises(InvalidParameter, match=r"campaign.operator: unknown key; .*go in a \[metadata\] table"):
        spec.load(path)


def test_metadata_is_no_part_of_the_plan(project):
    plain = spec.plan(spec.load(write(project / "a.toml", campaign_text())))
    tagged = spec.plan(spec.load(write(project / "b.toml", campaign_text(extra=META))))
    assert plain[1] == tagged[1] and [p.id for p in plain[0]] == [p.id for p in tagged[0]]


def test_metadata_reaches_the_ledger_every_log_the_results_api_and_the_catalog(project):
    assert (
        main(["run", str(write(project / "tagged.toml", campaign_text(name="tagged", extra=META))), "--workers", "1"])
        == 0
    )
    assert main(["run", str(write(project / "other.toml", campaign_text(name="other"))), "--workers", "1"]) == 0
    expected = {
        "operator": "Ana",
        "sample": "motor #3, new brushes",
        "tags": ["friction", "batch-7"],
        "repeat": 2,
        "calibrated": "2026-12-01",
    }
    with sqlite3.connect(project / "data" / "tagged" / "ledger.sqlite") as db:
        stored = db.execute("SELECT value FROM meta WHERE key = 'metadata'").fetchone()[0]
        logs = [r[0] for r in db.execute("SELECT log_path FROM points")]
    assert json.loads(stored) == expected
    assert len(logs) == 9 and all(
        read_run(project / "data" / "tagged" / p).metadata["metadata"] == expected for p in logs
    )
    campaign = open_campaign(project / "data" / "tagged")
    assert campaign.metadata == expected
    assert campaign.run(campaign.table()["id"].iloc[0]).campaign_metadata == expected
    assert open_campaign(project / "data" / "other").metadata == {}
    catalog = Catalog.find(project / "data")
    assert list(catalog.search(operator="ana")) == ["tagged"]  # strings without case
    assert list(catalog.search(tags="batch-7", repeat=2)) == ["tagged"]  # a tag among the list
    assert list(catalog.search("BRUSHES")) == ["tagged"]  # free text in any value
    assert list(catalog.search(operator="Bo")) == [] and list(catalog.search(repeat=True)) == []
    assert len(catalog.search()) == 2
