"""Issue 26: the metrics table is built from the ledger and written to metrics.csv/.parquet a chunk
at a time (bounded memory at 10^6 points); the result must equal the plain way — one DataFrame of
every row, one ``to_csv`` and one ``to_parquet`` — whatever the chunk boundaries."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from labrunner.analysis import table, table_files, table_rows


def _rows(n: int) -> list[dict]:
    """Ledger-like rows: varied outcomes, a monitor only where aborted, a text parameter whose
    values differ between chunks, a metric only some rows have, unfinished points at the end."""
    out = []
    for i in range(n):
        finished = i < n - 3
        outcome = ("completed", "aborted", "no-motion", "failed")[i % 4] if finished else None
        metrics = {"rms_error": 0.1 * i, "input_energy": float(i), "max_abs_input": 2.0, "n_samples": 100 + i}
        if i % 5 == 0:
            metrics["rms_error@rest"] = 1.0 / (i + 1)
        record = {"status": outcome, "monitor": "du_dt", "time": 0.5, "value": 3.0} if outcome == "aborted" else {}
        out.append(
            {
                "seq": i,
                "id": f"p{i:04d}",
                "state": "done" if finished else "planned",
                "outcome": outcome,
                "outcome_json": json.dumps(record) if finished else None,
                "parameters": json.dumps({"controller.k_p": 1.0 + i, "controller.diff": f"kind{i // 4}"}),
                "attempts": 1 if finished else 0,
                "log_path": f"runs/p{i:04d}.mcap" if finished and outcome != "failed" else None,
                "metrics_json": json.dumps(metrics) if finished and outcome != "failed" else None,
                "rms_error": None,
                "input_energy": None,
                "max_abs_input": None,
            }
        )
    return out


def _reference(rows: list[dict]) -> pd.DataFrame:
    """The table as one DataFrame of every row (the plain way, before chunking)."""
    frame, _ = table_rows.chunk_frame({k: [r[k] for r in rows] for k in rows[0]})
    return frame


@pytest.mark.parametrize("chunk", [1, 3, 4, 1000])
def test_ledger_frame_in_chunks_equals_one_frame_of_every_row(monkeypatch, chunk):
    rows = _rows(23)
    monkeypatch.setattr(table_rows, "CHUNK_ROWS", chunk)
    seen = []
    chunks = table_rows.in_chunks(iter(rows))
    frame, missing = table.ledger_frame(chunks, lambda start, part, absent: seen.append((start, len(part["id"]))))
    assert seen == [(s, min(chunk, 23 - s)) for s in range(0, 23, chunk)]
    assert missing == []
    reference = _reference(rows)
    assert list(frame.columns) == list(reference.columns)
    for col in reference.columns:
        expected = reference[col].reindex(range(len(rows)))
        if isinstance(frame[col].dtype, pd.CategoricalDtype):
            assert frame[col].astype(object).where(frame[col].notna(), None).tolist() == [
                None if pd.isna(v) else v for v in expected
            ], col
        else:
            pd.testing.assert_series_equal(frame[col], expected, check_dtype=False, check_names=False, obj=col)
    assert isinstance(frame["outcome"].dtype, pd.CategoricalDtype)
    assert isinstance(frame["controller.diff"].dtype, pd.CategoricalDtype)
    assert frame["id"].dtype == "str" and frame["log_path"].dtype == "str"


@pytest.mark.parametrize("rows_at_a_time", [2, 7, 100_000])
def test_written_files_equal_one_to_csv_and_to_parquet_of_the_whole_table(tmp_path, monkeypatch, rows_at_a_time):
    directory = tmp_path / "c"
    (directory / "runs").mkdir(parents=True)
    monkeypatch.setattr(table_rows, "CHUNK_ROWS", 4)
    frame, _ = table.ledger_frame(table_rows.in_chunks(_rows(23)))
    table.split_aborted(frame)
    frame["n_samples"] = frame["n_samples"].astype("Int64")
    frame["log_state"] = table.log_states(frame["log_path"], [])
    frame["empty_text"] = None  # a column no row fills
    monkeypatch.setattr(table_files, "ROWS_AT_A_TIME", rows_at_a_time)
    csv, parquet = table_files.write_table(frame, directory / "report", directory)
    # the reference: the whole table, log paths relative, text as the files hold it, in one go
    whole = table.ordered(frame.assign(log_path=table_files.relative_paths(frame["log_path"], directory, csv.parent)))
    whole["metrics_version"] = table.METRICS_VERSION
    whole = whole.astype({c: "str" for c in whole.columns if isinstance(whole[c].dtype, pd.CategoricalDtype)})
    whole = whole.astype({c: "string" for c in whole.columns if whole[c].dtype == object})
    assert csv.read_text() == whole.to_csv(index=False)
    expected_parquet = tmp_path / "whole.parquet"
    whole.to_parquet(expected_parquet, index=False)
    import pyarrow.parquet as pq

    assert pq.read_schema(parquet).remove_metadata() == pq.read_schema(expected_parquet).remove_metadata()
    pd.testing.assert_frame_equal(pd.read_parquet(parquet), pd.read_parquet(expected_parquet))
    assert pd.read_csv(csv)["log_path"].dropna().str.startswith("../runs/").all()
    assert not list((directory / "report").glob(".*.tmp"))


def test_log_states_of_problem_paths(tmp_path):
    paths = pd.Series(["runs/a.mcap", None, "runs/b.mcap", "runs/c.mcap"], dtype="str")
    problems = [
        {"path": "runs/b.mcap", "kind": "foreign", "detail": ""},
        {"path": "runs/c.mcap", "kind": "torn", "detail": ""},
        {"path": "quarantine/x", "kind": "quarantined", "detail": ""},
    ]
    states = table.log_states(paths, problems)
    assert [None if pd.isna(s) else s for s in states] == ["ok", None, "foreign", "torn"]
    assert np.array_equal(states.isna().to_numpy(), paths.isna().to_numpy())


def _random_table(n: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    outcome = rng.choice(["completed", "aborted", "failed", "no-motion", "planned"], n)
    rms = np.round(rng.random(n), 1) + 0.05  # ties
    rms[rng.random(n) < 0.2] = np.nan
    oscillating = (rng.random(n) < 0.3).astype(float)  # the detector's flag (issue 36: one was named "best")
    first = int(np.flatnonzero(outcome == "completed")[0])
    rms[first], oscillating[first] = 0.01, 1.0  # the lowest RMS of all, but oscillating
    frame = pd.DataFrame(
        {"seq": np.arange(n), "id": [f"p{i}" for i in range(n)], "rms_error": rms, "oscillating": oscillating}
    )
    frame["outcome"] = pd.Categorical(outcome)
    return frame.sample(frac=1.0, random_state=seed).reset_index(drop=True)  # seq not in row order


@pytest.mark.parametrize("seed", range(5))
def test_report_rows_and_chosen_runs_equal_the_plain_selections(monkeypatch, seed):
    from labrunner.analysis import campaign_report, selection

    frame = _random_table(200, seed)
    monkeypatch.setattr(campaign_report, "TABLE_ROWS", 40)
    # the plain way: copies of row subsets
    best = frame.nsmallest(20, "rms_error")
    rest = frame.drop(index=best.index)
    trouble = rest[rest["outcome"].isin(["aborted", "failed"])].head(10)
    others = rest.drop(index=trouble.index).head(40 - len(best) - len(trouble))
    pd.testing.assert_frame_equal(campaign_report._table_rows(frame), pd.concat([best, trouble, others]))
    done = frame[(frame["outcome"] == "completed") & np.isfinite(frame["rms_error"]) & (frame["oscillating"] == 0)]
    assert frame["rms_error"].min() < done["rms_error"].min()  # an oscillating run has the lowest RMS
    aborted = frame[frame["outcome"] == "aborted"]
    expected = {
        "best": done.loc[done["rms_error"].idxmin()],
        "worst completed": done.loc[done["rms_error"].idxmax()],
        "first aborted": aborted.loc[aborted["seq"].idxmin()],
    }
    chosen = selection.chosen_runs(frame)
    assert list(chosen) == list(expected)
    for label, row in expected.items():
        pd.testing.assert_series_equal(chosen[label], row)
