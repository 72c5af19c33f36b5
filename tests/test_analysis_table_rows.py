"""Issue 34 part 5: the metrics table is built a column at a time (labrunner.analysis.table_rows);
it must be the table the per-row path built before, value for value, type for type and column for
column. The reference below is that path as it was (one record a row, ``DataFrame.from_records``),
compared on hand-made ledger rows that reach every branch and on a real campaign's ledger."""

from __future__ import annotations

import json
import math
import shutil
import sqlite3

import numpy as np
import pandas as pd
import pytest
from test_analysis_table_files import _rows
from test_campaign_support import MOTOR_RIG, campaign_text, cli, write

import labrunner
from labrunner.analysis import table, table_rows
from labrunner.campaign.rig_timing import timing_counts
from labrunner.rigs.device.lawflag import arithmetic_of, flag_of

LEGACY = ("rms_error", "input_energy", "max_abs_input")


def _float(value):
    return float(value) if value is not None else float("nan")


def _per_row_columns(rows):
    """:func:`_per_row_frame` as the columns :func:`table_rows.chunk_columns` gives."""
    frame, missing = _per_row_frame(rows)
    return {k: frame[k].to_numpy() for k in frame.columns}, missing


def _per_row_frame(rows):
    """The chunk frame as the per-row path built it (labrunner before issue 34 part 5)."""
    records, missing = [], []
    for i, r in enumerate(rows):
        outcome = json.loads(r["outcome_json"]) if r["outcome_json"] else {}
        params = json.loads(r["parameters"])
        aborted = r["outcome"] == "aborted"
        text = r.get("metrics_json")
        metrics = {k: np.nan if v is None else v for k, v in json.loads(text).items()} if text else None
        if metrics is None:
            metrics = {k: _float(r.get(k)) for k in LEGACY}
            if r.get("log_path"):
                missing.append(i)
        records.append(
            {
                "seq": r["seq"],
                "id": r["id"],
                "outcome": r["outcome"] or r["state"],
                "monitor": outcome.get("monitor"),
                "abort_time": _float(outcome.get("time")) if aborted else np.nan,
                "abort_value": _float(outcome.get("value")) if aborted else np.nan,
                "attempts": r["attempts"],
                "log_path": r["log_path"],
                "torn": False,
                "law_check": flag_of(outcome),
                "law_arithmetic": arithmetic_of(outcome),
                **{k: v for k, v in params.items() if isinstance(v, (int, float, str, bool))},
                **metrics,
                **timing_counts(outcome.get("diagnostics")),
            }
        )
    return pd.DataFrame.from_records(records), missing


def _rows_of(chunk):
    """A column-wise chunk as one dict a row, as the per-row path read the ledger."""
    return [dict(zip(chunk, values)) for values in zip(*chunk.values())]


def _assert_same(rows):
    frame, missing = table_rows.chunk_frame(next(table_rows.in_chunks(rows)))
    reference, reference_missing = _per_row_frame(rows)
    assert missing == reference_missing
    pd.testing.assert_frame_equal(frame, reference, check_exact=True)


def _device_rows():
    """Rows of a device-loop / real-rig campaign: law-check flags and timing counts in the outcome's
    diagnostics, an integer count absent from some rows, a parameter that is a list (left out)."""
    rows = _rows(12)
    for i, r in enumerate(rows[:9]):
        diagnostics = {
            "law_check": {
                "flag": ("ok", "diverged at 12", "not-checked")[i % 3],
                "arithmetic": ("float64", "float32")[i % 2],
            }
        }
        if i % 2:
            diagnostics["device_loop"] = {"overruns": i}
        else:
            diagnostics["host"] = {"late_ticks": 2 * i, "overruns": 1}
        r["outcome_json"] = json.dumps({"status": r["outcome"], "diagnostics": diagnostics})
        r["parameters"] = json.dumps({"controller.k_p": float(i), "reference.levels": [0, 1], "rig.flag": i % 2 == 0})
    return rows


def _edge_rows():
    """Stored metrics Arrow would type otherwise than a record a row (a boolean, a text), NaN and
    Infinity of older ledgers, an empty record, a row of an older ledger (no metrics text) first."""
    rows = _rows(8)
    rows[0]["metrics_json"], rows[0]["rms_error"] = None, 0.25
    rows[1]["metrics_json"] = json.dumps({"rms_error": float("nan"), "n_samples": 3, "max_current": None})
    rows[2]["metrics_json"] = "{}"
    rows[3]["metrics_json"] = '{"rms_error": Infinity, "n_samples": 4.0}'
    return rows


def _before_metrics_json():
    """Rows of a ledger from before ``metrics_json`` and the logs' fingerprints were columns."""
    return [{k: v for k, v in r.items() if k != "metrics_json"} for r in _rows(9)]


@pytest.mark.parametrize(
    "rows",
    [
        _rows(23),
        [r for r in _rows(20) if r["metrics_json"]],
        _device_rows(),
        _edge_rows(),
        _before_metrics_json(),
        _rows(1),
    ],
    ids=["outcomes", "all-with-metrics", "device-diagnostics", "older-ledgers", "no-metrics-column", "one-row"],
)
def test_columns_equal_the_per_row_frame(rows):
    _assert_same(rows)


@pytest.mark.parametrize("value", ["true", '"high"', "[1, 2]"])
def test_a_metric_arrow_would_type_otherwise_is_typed_as_a_record_a_row(value):
    rows = _rows(10)
    rows[4]["metrics_json"] = rows[4]["metrics_json"][:-1] + f', "odd": {value}}}'
    _assert_same(rows)


def test_parsed_metrics_are_bit_exact():
    """Arrow's number parsing against Python's: every stored digit string gives the same double."""
    rng = np.random.default_rng(7)
    values = np.concatenate([rng.standard_normal(500) * 10.0 ** rng.integers(-300, 300, 500), [5e-324, 1.7e308]])
    values = [float(v) for v in values]
    rows = _rows(len(values))
    for r, v in zip(rows, values):
        r["metrics_json"] = json.dumps({"rms_error": v, "n_samples": 1})
    frame, _ = table_rows.chunk_frame(next(table_rows.in_chunks(rows)))
    assert frame["rms_error"].to_numpy().tobytes() == np.array([json.loads(json.dumps(v)) for v in values]).tobytes()
    assert not any(math.isnan(v) for v in frame["rms_error"])


def test_a_real_campaigns_table_equals_the_per_row_path(tmp_path, monkeypatch):
    """``open_campaign(...).table()`` of a real motor campaign (completed and aborted runs, two
    points never run), and of a copy whose ledger holds no metrics texts (an older ledger: its
    logs are read), equals the table the per-row path builds from the same ledger."""
    write(tmp_path / "rigs" / "motor.toml", MOTOR_RIG)
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    grid = '"controller.gamma" = { log10 = [0.0, 4.0], num = 3 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 3 }'
    path = write(tmp_path / "campaigns" / "c.toml", campaign_text("c", duration=1.0, grid=grid))
    directory = tmp_path / "c"
    done = cli("run", str(path), "--out", str(directory), "--workers", "1", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    older = tmp_path / "older"
    shutil.copytree(directory, older)
    with sqlite3.connect(older / "ledger.sqlite") as db:
        db.execute("UPDATE points SET metrics_json = NULL")
        db.execute("UPDATE points SET state = 'planned', outcome = NULL, log_path = NULL WHERE seq >= 7")
    for d in (directory, older):
        new = labrunner.open_campaign(d).table()
        monkeypatch.setattr(table, "chunk_columns", lambda chunk: _per_row_columns(_rows_of(chunk)))
        reference = labrunner.open_campaign(d).table()
        monkeypatch.undo()
        assert set(new["outcome"]) >= {"completed", "aborted"}
        pd.testing.assert_frame_equal(new, reference, check_exact=True)
