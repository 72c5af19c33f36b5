"""The results API (labrunner.open_campaign, open_run, Catalog) on a real (simulated) campaign,
checked against independent readers: pandas reading the metrics.csv that ``analyse`` writes, the
official ``mcap`` reader with protobuf classes built from each log's own schema, and the ledger
as SQLite gives it."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from test_campaign_support import MOTOR_RIG, campaign_text, write
from test_logs import bits, classes_from_file

import labrunner
from labrunner.cli import main
from labrunner.errors import InvalidParameter

GRID = '"controller.gamma" = { log10 = [0.0, 4.0], num = 3 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 4 }'
ROOT = Path(__file__).resolve().parents[1]


def _run(args: list[str]) -> None:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        assert main(args) == 0, err.getvalue()


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """Two campaigns on the motor twin (3 × 4 γ–k_p, early aborts at small γ; and a 2-point one);
    the first is analysed only after its table has been taken from the ledger alone."""
    root = tmp_path_factory.mktemp("project")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(root / "rigs" / "motor.toml", MOTOR_RIG)
    sweep = write(root / "campaigns" / "sweep.toml", campaign_text("sweep", duration=2.0, grid=GRID))
    small = write(
        root / "campaigns" / "small.toml",
        campaign_text("small", duration=1.0, grid='"controller.k_p" = { values = [5.0, 20.0] }'),
    )
    _run(["run", str(sweep), "--out", str(root / "data" / "sweep"), "--workers", "1"])
    _run(["run", str(small), "--out", str(root / "data" / "small"), "--workers", "1"])
    before = labrunner.open_campaign(root / "data" / "sweep").table()
    _run(["analyse", str(root / "data" / "sweep"), "--workers", "1"])
    return root, before


def test_table_is_metrics_csv_with_or_without_analyse(project):
    root, before = project
    directory = root / "data" / "sweep"
    csv = pd.read_csv(directory / "report" / "metrics.csv")
    after = labrunner.open_campaign(directory).table()
    for table in (before, after):
        assert list(table.columns) == list(csv.columns)  # the same names, in the same order
        assert table["id"].tolist() == csv["id"].tolist()
        resolved = [str((directory / "report" / p).resolve()) for p in csv["log_path"]]
        assert table["log_path"].tolist() == resolved  # absolute here, relative to report/ in the file
        for column in csv.columns.drop("log_path"):
            if pd.api.types.is_numeric_dtype(csv[column]) and pd.api.types.is_numeric_dtype(table[column]):
                assert np.allclose(
                    table[column].to_numpy(float), csv[column].to_numpy(float), rtol=1e-12, equal_nan=True
                ), column
            else:  # text; a column empty in every row (law_check of twin runs) reads back from CSV as NaN
                assert table[column].astype(object).fillna("").astype(str).tolist() == (
                    csv[column].astype(object).fillna("").astype(str).tolist()
                )
    assert set(after["outcome"]) >= {"completed", "aborted"}
    aborted = after[after["outcome"] == "aborted"]
    assert aborted["rms_error"].isna().all() and aborted["rms_error_until_abort"].notna().all()
    with sqlite3.connect(directory / "ledger.sqlite") as db:
        ledger = dict(db.execute("SELECT id, metrics_json FROM points"))
    for row in after.itertuples():
        committed = json.loads(ledger[row.id])["rms_error"]
        shown = row.rms_error if row.outcome != "aborted" else row.rms_error_until_abort
        assert shown == committed


def test_report_table_names_parameters_as_the_csv_does(project):
    root, _ = project
    html = (root / "data" / "sweep" / "report" / "index.html").read_text(encoding="utf-8")
    assert "<th>controller.k_p</th>" in html and "<th>controller.gamma</th>" in html
    assert "<th>k_p</th>" not in html


def test_select_by_parameters(project):
    root, _ = project
    campaign = labrunner.open_campaign(root / "data" / "sweep")
    table = campaign.table()
    assert campaign.parameters == ["controller.gamma", "controller.k_p"]
    k_p = sorted(table["controller.k_p"].unique())
    chosen = campaign.select(k_p=k_p[1])
    assert len(chosen) == 3 and np.allclose(chosen["controller.k_p"], k_p[1])
    assert campaign.select({"controller.k_p": k_p[1]}).equals(chosen)
    assert (
        len(campaign.select(k_p=[k_p[0], k_p[3]], outcome="completed"))
        == ((table["controller.k_p"].isin([k_p[0], k_p[3]])) & (table["outcome"] == "completed")).sum()
    )
    ranged = campaign.select(gamma=slice(1.0, 100.0))
    assert ranged["controller.gamma"].between(1.0, 100.0).all() and len(ranged) == 8
    assert (
        len(campaign.select(rms_error=lambda c: c < c.median()))
        == (table["rms_error"] < table["rms_error"].median()).sum()
    )
    with pytest.raises(InvalidParameter, match="zeta: is no column"):
        campaign.select(zeta=1.0)
    with pytest.raises(InvalidParameter, match="no point of campaign"):
        campaign.run("nope")


def test_run_signals_units_and_outcome_match_the_official_reader(project):
    root, _ = project
    campaign = labrunner.open_campaign(root / "data" / "sweep")
    table = campaign.table()
    shapes = set()
    for outcome in ("completed", "aborted"):
        row = table[table["outcome"] == outcome].iloc[0]
        run = campaign.run(row["id"])
        assert run.outcome["status"] == outcome and tuple(run.outcome)[:7] == labrunner.OUTCOME_KEYS
        shapes.add(tuple(run.outcome))
        classes = classes_from_file(row["log_path"])
        with open(row["log_path"], "rb") as f:
            decoded = [(m.sequence, classes[s.name].FromString(m.data)) for s, _, m in make_reader(f).iter_messages()]
        signals = run.signals
        assert [k for k, _ in decoded] == list(range(len(signals)))
        assert np.array_equal(signals.index.to_numpy(), np.arange(len(signals)) / run.fs)
        fields = [f.name for f in decoded[0][1].DESCRIPTOR.fields]
        for name, field in zip(signals.columns, fields, strict=True):
            assert field == name or field == f"{name}__{run.units[name].replace('/', '_per_').replace('²', '2')}"
            assert np.array_equal(bits([getattr(m, field) for _, m in decoded]), bits(signals[name].to_numpy()))
        assert signals.attrs["units"]["omega"] == "rad/s" and run.units["u"] == "V"
        assert run.outcome["n_samples"] == len(signals) == row["n_samples"]
        assert run.parameters["controller.k_p"] == row["controller.k_p"] and run.config["controller"]["kind"] == "mfc1"
        assert run.diagnostics == {}  # a twin run
        if outcome == "aborted":
            assert run.outcome["time"] == pytest.approx(row["abort_time"]) and run.outcome["monitor"] == row["monitor"]
    assert len(shapes) == 1  # one shape for every outcome


def test_point_by_time_signals_pad_aborted_runs(project):
    root, _ = project
    campaign = labrunner.open_campaign(root / "data" / "sweep")
    rows = campaign.select(outcome=["completed", "aborted"])
    dataset = campaign.signals(rows, names=["omega", "u"], grid=False)
    assert dict(dataset.sizes) == {"point": len(rows), "time": 400}  # 2 s at 200 Hz
    assert dataset["omega"].attrs["units"] == "rad/s" and dataset["time"].attrs["units"] == "s"
    for point in rows["id"]:
        run = campaign.run(point)
        n = int(dataset["n_samples"].sel(point=point))
        assert n == len(run.signals)
        omega = dataset["omega"].sel(point=point).to_numpy()
        assert np.array_equal(bits(omega[:n]), bits(run.signals["omega"].to_numpy()))
        assert np.isnan(omega[n:]).all() and not dataset["valid"].sel(point=point)[n:].any()
        assert dataset["valid"].sel(point=point)[:n].all()
    assert (dataset["n_samples"] < 400).any()  # some runs were aborted, and padded
    assert set(dataset["outcome"].to_numpy()) == {"completed", "aborted"}
    assert np.array_equal(dataset["controller.k_p"].to_numpy(), rows["controller.k_p"].to_numpy())
    with pytest.raises(InvalidParameter, match="logs no"):
        campaign.signals(rows, names=["nope"])


def test_signals_of_a_full_grid_have_the_parameters_as_dimensions(project):
    root, _ = project
    campaign = labrunner.open_campaign(root / "data" / "sweep")
    table = campaign.table()
    assert table["log_path"].map(lambda p: isinstance(p, str)).all()  # every point of the 3 × 4 grid ran
    dataset = campaign.signals(names=["omega", "u"])
    assert dataset["omega"].dims == ("gamma", "k_p", "time") and dict(dataset.sizes) == {
        "gamma": 3,
        "k_p": 4,
        "time": 400,
    }
    assert np.array_equal(dataset["gamma"], np.sort(table["controller.gamma"].unique()))
    assert np.array_equal(dataset["k_p"], np.sort(table["controller.k_p"].unique()))
    aborted = table[table["outcome"] == "aborted"].iloc[0]
    chosen = [table.iloc[0], table.iloc[-1], aborted]
    for row in chosen:
        cell = dataset.sel(gamma=row["controller.gamma"], k_p=row["controller.k_p"])
        assert cell["point"].item() == row["id"] and cell["outcome"].item() == row["outcome"]
        run = campaign.run(row["id"])
        n = int(cell["n_samples"])
        assert n == len(run.signals) and bool(cell["valid"][:n].all()) and not cell["valid"][n:].any()
        for name in ("omega", "u"):
            assert np.array_equal(bits(cell[name].to_numpy()[:n]), bits(run.signals[name].to_numpy()))
            assert np.isnan(cell[name].to_numpy()[n:]).all()
    assert dataset["n_samples"].dtype == np.int64 and dataset["valid"].dtype == bool

    one_gamma = campaign.select(gamma=aborted["controller.gamma"])
    line = campaign.signals(one_gamma, names=["u"])
    assert line["u"].dims == ("k_p", "time") and np.all(np.diff(line["k_p"]) > 0)  # gamma does not vary
    row = one_gamma.iloc[-1]
    cell, run = line.sel(k_p=row["controller.k_p"]), campaign.run(row["id"])
    assert cell["point"].item() == row["id"]
    assert np.array_equal(bits(cell["u"].to_numpy()[: len(run.signals)]), bits(run.signals["u"].to_numpy()))
    holed = table.drop(index=table.index[3])  # 11 of 12: no full grid, so one dimension per point
    assert campaign.signals(holed, names=["u"])["u"].dims == ("point", "time")
    assert campaign.signals(names=["u"], grid=False)["u"].dims == ("point", "time")


def test_xarray_is_optional_with_a_clear_error(project, monkeypatch):
    root, _ = project
    campaign = labrunner.open_campaign(root / "data" / "sweep")
    monkeypatch.setitem(sys.modules, "xarray", None)
    with pytest.raises(ImportError, match=r"need xarray, which is not installed: pip install xarray"):
        campaign.signals()
    assert len(campaign.run(campaign.table()["id"].iloc[-1]).signals) > 0  # pandas needs no xarray


def test_catalog_over_campaign_directories(project):
    root, _ = project
    catalog = labrunner.Catalog.find(root / "data")
    assert sorted(catalog) == ["small", "sweep"] and len(catalog) == 2
    table = catalog.table()
    assert table.columns[0] == "campaign"
    assert (table["campaign"] == "small").sum() == 2 and (table["campaign"] == "sweep").sum() == 12
    assert table.loc[table["campaign"] == "small", "controller.gamma"].isna().all()  # not a parameter there
    assert catalog["small"].table()["controller.k_p"].tolist() == [5.0, 20.0]
    with pytest.raises(InvalidParameter, match="is not in the catalog"):
        catalog["nope"]
    with pytest.raises(InvalidParameter, match="holds no campaign ledger"):
        labrunner.open_campaign(root / "campaigns")


def test_example_script_runs_on_a_campaign(project):
    root, _ = project
    out = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "results_in_python.py"), str(root / "data" / "sweep")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "sweep: 12 points; parameters ['controller.gamma', 'controller.k_p']" in out.stdout
    assert "outcome completed" in out.stdout and "samples logged" in out.stdout


def test_report_shows_a_bounded_runs_table_of_a_large_campaign(project, monkeypatch):
    """Past TABLE_ROWS points the report's table keeps the best half by rms_error, then aborted
    runs, then the rest in grid order, and says so; metrics.csv keeps every point."""
    from labrunner.analysis import campaign_report

    root, _ = project
    directory = root / "data" / "sweep"
    frame = labrunner.open_campaign(directory).table()
    monkeypatch.setattr(campaign_report, "TABLE_ROWS", 6)
    rows = campaign_report._table_rows(frame)
    assert len(rows) == 6 and rows["id"].is_unique
    assert rows["id"].iloc[:3].tolist() == frame.nsmallest(3, "rms_error")["id"].tolist()
    aborted = frame[frame["outcome"] == "aborted"]["id"].head(1).tolist()
    assert rows["id"].iloc[3:4].tolist() == aborted
    _run(["analyse", str(directory), "--workers", "1"])
    html = (directory / "report" / "index.html").read_text(encoding="utf-8")
    assert "6 of the 12 points (the best 3 by rms_error" in html and html.count("<tr>") >= 6
    assert len(pd.read_csv(directory / "report" / "metrics.csv")) == 12


def _strict(text: str):
    """json.loads that refuses NaN and Infinity, as JSON.parse, jq and Foxglove do."""

    def refuse(constant: str):
        raise ValueError(f"bare {constant} in stored JSON")

    return json.loads(text, parse_constant=refuse)


def test_stored_json_is_strict(project):
    """The ledger's JSON columns and every run log's JSON records parse as strict JSON; an
    undefined metric (the motor twin has no current: max_current) is null there and NaN in the
    table."""
    root, _ = project
    directory = root / "data" / "sweep"
    with sqlite3.connect(directory / "ledger.sqlite") as db:
        rows = db.execute("SELECT parameters, outcome_json, metrics_json FROM points").fetchall()
    metrics = [_strict(m) for _, _, m in rows]
    for parameters, outcome, _ in rows:
        _strict(parameters), _strict(outcome)
    assert all(m["max_current"] is None for m in metrics)
    assert labrunner.open_campaign(directory).table()["max_current"].isna().all()
    for log in (directory / "runs").glob("*.mcap"):
        with open(log, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if set(record.metadata) == {"json"}:
                    _strict(record.metadata["json"])


def test_a_ledger_whose_ids_were_changed_is_refused_when_the_table_is_built(project, tmp_path):
    """Opening reads only the ledger's structure (cheap at 10^6 points); the checks that read every
    row run once, for the table, and still refuse a tampered ledger in one line."""
    from labrunner.campaign.integrity import LedgerDamaged

    root, _ = project
    copy = shutil.copytree(root / "data" / "small", tmp_path / "small")
    with sqlite3.connect(copy / "ledger.sqlite") as db:
        db.execute("UPDATE points SET id = 'ffffffffffffffff' WHERE seq = 0")
    campaign = labrunner.open_campaign(copy)
    with pytest.raises(LedgerDamaged, match="ids changed"):
        campaign.table()
