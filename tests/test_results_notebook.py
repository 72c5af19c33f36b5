"""Issue 36, first-week friction 5: the results API in a notebook — a campaign's and a run's repr
(text and HTML: counts, outcomes, parameters, date), a run by a prefix of its id, units of the
table's columns (``DataFrame.attrs["units"]``), and a catalog's summary (rig, date, description),
its latest campaign and its table's first columns. Checked against the ledger as SQLite gives it
and the logs' own channel records."""

from __future__ import annotations

import sqlite3
import time

import pytest
from test_campaign_support import MOTOR_RIG, campaign_text, cli, write

import labrunner
from labrunner.errors import InvalidParameter

GRID = '"controller.gamma" = { log10 = [0.0, 4.0], num = 4 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 3 }'


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("notebook")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(root / "rigs" / "motor.toml", MOTOR_RIG)
    for name, grid, description in (
        ("first", GRID, "gains <first> & more"),
        ("second", '"controller.k_p" = { values = [5.0, 20.0] }', "two points"),
    ):
        body = campaign_text(name, duration=1.0, grid=grid).replace("test campaign", description)
        path = write(root / "campaigns" / f"{name}.toml", body)
        done = cli("run", str(path), "--out", str(root / "data" / name), "--workers", "1", cwd=root)
        assert done.returncode == 0, done.stderr
        time.sleep(0.05)  # the second is created later
    return root / "data"


def _counts(directory) -> dict[str, int]:
    with sqlite3.connect(directory / "ledger.sqlite") as db:
        return dict(db.execute("SELECT COALESCE(outcome, state), COUNT(*) FROM points GROUP BY 1"))


def test_campaign_repr_says_counts_outcomes_parameters_and_date(project):
    campaign = labrunner.open_campaign(project / "first")
    text = repr(campaign)
    counts = _counts(project / "first")
    assert f"points       {sum(counts.values())}: " in text
    for outcome, n in counts.items():
        assert f"{n} {outcome}" in text
    assert "controller.gamma, controller.k_p" in text and "gains <first> & more" in text
    assert time.strftime("%Y-%m-%d", time.gmtime()) in text and "UTC" in text
    page = campaign._repr_html_()
    assert "gains &lt;first&gt; &amp; more" in page and "<first>" not in page  # escaped


def test_run_repr_and_a_run_by_id_prefix(project):
    campaign = labrunner.open_campaign(project / "first")
    table = campaign.table()
    ids = table["id"].tolist()
    unique = next(p for i in ids for p in (i[:k] for k in range(1, len(i))) if sum(j.startswith(p) for j in ids) == 1)
    run = campaign.run(unique)
    assert run.id == next(i for i in ids if i.startswith(unique))
    text = repr(run)
    row = table.set_index("id").loc[run.id]
    assert run.id in text and row["outcome"] in text
    assert f"{int(row['n_samples'])} at 200 Hz" in text
    assert "controller.k_p = " in text and "<td>" in run._repr_html_()
    shared = next((i[:1] for i in ids if sum(j.startswith(i[:1]) for j in ids) > 1), None)
    if shared is not None:
        with pytest.raises(InvalidParameter, match="give more of it"):
            campaign.run(shared)
    with pytest.raises(InvalidParameter, match="no point"):
        campaign.run("zz")
    assert "nonexistent" in repr(labrunner.open_run(project / "nonexistent.mcap"))  # no raise


def test_units_of_the_table_columns_are_the_logs(project):
    campaign = labrunner.open_campaign(project / "first")
    table = campaign.table()
    units = table.attrs["units"]
    run = campaign.run(int(table.loc[table["outcome"] == "completed", "seq"].iloc[0]))
    assert units["rms_e_omega"] == run.units["e_omega"] == "rad/s"
    assert units["rms_error"] == units["rms_error_until_abort"] == "rad/s"
    assert units["max_abs_input"] == run.units["u"] == "V" and units["input_energy"] == "V²"
    assert units["controller.k_p"] == "1/s" and units["abort_time"] == "s"
    assert "outcome" not in units and "seq" not in units
    science = campaign.table(housekeeping=False)
    assert list(table.columns[-3:]) == ["log_size", "log_mtime_ns", "metrics_version"]
    assert list(science.columns) == list(table.columns[:-3]) and science.attrs["units"] == units


def test_catalog_summary_latest_and_table(project):
    catalog = labrunner.Catalog.find(project)
    summary = catalog.summary().set_index("campaign")
    for name in ("first", "second"):
        counts = _counts(project / name)
        assert summary.loc[name, "points"] == sum(counts.values())
        assert all(summary.loc[name, outcome] == n for outcome, n in counts.items())
        assert summary.loc[name, "rig"] == "rigs/motor.toml"
    assert summary.loc["second", "description"] == "two points"
    assert summary.loc["second", "date"] > summary.loc["first", "date"]
    assert catalog.latest().name == "second"
    table = catalog.table()
    assert list(table.columns[:4]) == ["campaign", "rig", "date", "description"]
    assert (table.loc[table["campaign"] == "second", "description"] == "two points").all()
