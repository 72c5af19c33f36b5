"""`labrunner analyse` on a synthetic campaign directory: table, cache, maps, report, damaged files."""

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from test_analysis_support import expected_metrics, make_campaign, outcome_of, tear

from labrunner.analysis.analyse import analyse
from labrunner.analysis.table import build_table
from labrunner.analysis.table_rows import in_chunks
from labrunner.campaign.ledger import Ledger
from labrunner.cli import main


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    d = tmp_path_factory.mktemp("campaign")
    points = make_campaign(d)
    return d, points, analyse(d, d / "r", workers=1)


def test_metrics_table_matches_hand_values(analysed):
    d, points, summary = analysed
    table = pd.read_parquet(d / "r" / "metrics.parquet")
    csv = pd.read_csv(d / "r" / "metrics.csv")
    assert len(table) == len(csv) == len(points) == summary["points"] == summary["runs"]
    for p in points:
        g, kp = p["params"]["controller.gamma"], p["params"]["controller.k_p"]
        row = table[table["id"] == p["id"]].iloc[0]
        rms, energy, umax = expected_metrics(g, kp)
        assert row["outcome"] == outcome_of(g, kp)
        suffix = "_until_abort" if row["outcome"] == "aborted" else ""  # an aborted run's metrics cover part of it
        assert row["rms_error" + suffix] == pytest.approx(rms) and row["rms_e_omega" + suffix] == pytest.approx(rms)
        assert row["input_energy" + suffix] == pytest.approx(energy) and row["max_abs_input" + suffix] == pytest.approx(
            umax
        )
        assert row["controller.gamma"] == g and row["controller.k_p"] == kp
        assert row["n_samples"] == (100 if suffix else 400)
    aborted = table[table["outcome"] == "aborted"]
    assert (aborted["monitor"] == "du_dt").all() and np.allclose(aborted["abort_time"], (400 // 4 - 1) / 200.0)
    assert aborted["rms_error"].isna().all() and aborted["input_energy"].isna().all()
    assert table["n_samples"].dtype == "Int64" and csv["n_samples"].dtype == np.int64 and csv["seq"].dtype == np.int64
    expected = {
        s: sum(
            outcome_of(**{"gamma": p["params"]["controller.gamma"], "k_p": p["params"]["controller.k_p"]}) == s
            for p in points
        )
        for s in ("completed", "aborted", "no-motion")
    }
    assert {k: summary["outcomes"][k] for k in expected} == expected
    best = min(
        (expected_metrics(p["params"]["controller.gamma"], p["params"]["controller.k_p"])[0], p["id"])
        for p in points
        if outcome_of(p["params"]["controller.gamma"], p["params"]["controller.k_p"]) == "completed"
    )
    assert summary["best"]["id"] == best[1] and summary["best"]["rms"] == pytest.approx(best[0])
    assert len(summary["maps"]) == 2 and len(summary["run_plots"]) == 3


def test_report_has_maps_runs_and_campaign(analysed):
    d, points, summary = analysed
    html = (d / "r" / "index.html").read_text()
    assert html.count("data:image/png;base64,") == len(summary["maps"]) + len(summary["run_plots"]) == 5
    assert summary["logs_read"] == 0  # every metric came from the ledger
    assert "best run" in html and "first aborted run" in html and "worst completed run" in html
    assert "ledger keeps no copy of the campaign file" in html  # this synthetic ledger has none


def test_recomputed_metrics_equal_the_ledgers(analysed, tmp_path):
    d, _, first = analysed
    again = analyse(d, tmp_path / "r", workers=1, recompute=True)
    assert again["logs_read"] == 16 and again["best"] == first["best"]
    pd.testing.assert_frame_equal(
        pd.read_parquet(d / "r" / "metrics.parquet").drop(
            columns=["log_path", "log_size", "log_mtime_ns"], errors="ignore"
        ),
        pd.read_parquet(tmp_path / "r" / "metrics.parquet").drop(columns=["log_path", "log_size", "log_mtime_ns"]),
        check_like=True,
        check_dtype=False,
    )


def test_ledger_without_metrics_is_read_from_logs_once(tmp_path):
    d = tmp_path / "old"
    make_campaign(d, legacy=True)
    first = analyse(d, d / "r", workers=1)
    second = analyse(d, d / "r", workers=1)
    assert first["logs_read"] == 16 and second["logs_read"] == 0  # the table caches what it read
    assert first["best"] == second["best"]
    a = pd.read_parquet(d / "r" / "metrics.parquet")
    assert np.allclose(a["rms_error"], pd.read_csv(d / "r" / "metrics.csv")["rms_error"], equal_nan=True)
    assert a["rms_e_omega"].notna().all() or a["rms_e_omega_until_abort"].notna().any()
    touched = d / "runs" / f"{first['best']['id']}.mcap"
    touched.write_bytes(touched.read_bytes())  # a rewritten log is read again
    assert analyse(d, d / "r", workers=1)["logs_read"] == 1


def test_parallel_reading_equals_serial(tmp_path):
    d = tmp_path / "big"
    make_campaign(d, gammas=tuple(np.logspace(0, 3, 9)), k_ps=tuple(np.logspace(-1, 2, 8)))  # 72 logs
    with Ledger.open_readonly(d) as ledger:
        rows = [dict(r) for r in ledger.rows()]
    chunks = list(in_chunks(rows))
    events: list[tuple[str, int]] = []
    serial = build_table(
        chunks,
        d,
        workers=1,
        recompute=True,
        announce=lambda n: events.append(("logs", n)),
        tick=lambda n: events.append(("read", n)),
    )
    parallel = build_table(chunks, d, workers=2, recompute=True)
    pd.testing.assert_frame_equal(serial.frame, parallel.frame)
    assert events == [("logs", 72)] + [("read", 1)] * 72  # the progress knows the total before the first log
    assert serial.n_read == parallel.n_read == 72 and not serial.problems


def test_torn_missing_unreadable_and_quarantined_files_are_reported(tmp_path):
    d = tmp_path / "damaged"
    points = make_campaign(d)
    tear(d / "runs" / f"{points[0]['id']}.mcap")
    (d / "runs" / f"{points[1]['id']}.mcap").unlink()
    (d / "runs" / f"{points[2]['id']}.mcap").write_bytes(b"not an mcap at all")
    (d / "quarantine").mkdir()
    (d / "quarantine" / "p9999-torn.mcap").write_bytes(b"\x89MCAP0\r\n half a file")
    with Ledger.open(d) as ledger:
        ledger.record_quarantine(
            "p0003", "runs/p0003.mcap", "quarantine/p0003-1.mcap", "torn log of a claimed point", 123
        )
    summary = analyse(d, workers=1)
    kinds = {(p["kind"], p["path"]) for p in summary["problems"]}
    assert ("torn", f"runs/{points[0]['id']}.mcap") in kinds
    assert ("missing", f"runs/{points[1]['id']}.mcap") in kinds
    assert ("unreadable", f"runs/{points[2]['id']}.mcap") in kinds
    assert ("quarantined", "quarantine/p0003-1.mcap") in kinds
    assert ("quarantined", "quarantine/p9999-torn.mcap") in kinds
    html = (d / "report" / "index.html").read_text()
    for name in ("p9999-torn.mcap", "p0003-1.mcap", f"{points[1]['id']}.mcap", f"{points[2]['id']}.mcap"):
        assert name in html
    table = pd.read_parquet(d / "report" / "metrics.parquet")
    # the missing log keeps the ledger's summary
    row = table[table["id"] == points[1]["id"]].iloc[0]
    g, kp = points[1]["params"]["controller.gamma"], points[1]["params"]["controller.k_p"]
    assert outcome_of(g, kp) == "aborted" and row["rms_error_until_abort"] == pytest.approx(expected_metrics(g, kp)[0])
    assert bool(table[table["id"] == points[0]["id"]]["torn"].iloc[0])
    # the table itself says which logs no longer back their rows, in both files, after log_path, torn
    for frame in (table, pd.read_csv(d / "report" / "metrics.csv")):
        state = dict(zip(frame["id"], frame["log_state"]))
        assert [state[p["id"]] for p in points[:3]] == ["torn", "missing", "unreadable"]
        assert {state[p["id"]] for p in points[3:]} == {"ok"}
        assert list(frame.columns).index("log_state") == list(frame.columns).index("log_path") + 2
    again = analyse(d, workers=1)  # from the cache of the first analysis: the same states
    assert {(p["kind"], p["path"]) for p in again["problems"]} == kinds
    assert pd.read_parquet(d / "report" / "metrics.parquet")["log_state"].tolist() == table["log_state"].tolist()


def test_unfinished_campaign_and_cli_json(tmp_path, capsys):
    d = tmp_path / "c"
    make_campaign(d)
    import sqlite3

    db = sqlite3.connect(d / "ledger.sqlite")
    db.execute("UPDATE points SET state = 'planned', outcome = NULL, log_path = NULL WHERE seq >= 12")
    db.commit()
    db.close()
    assert main(["analyse", str(d), "--json", "--workers", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["points"] == 16 and out["runs"] == 12 and out["outcomes"]["planned"] == 4
    assert set(out) >= {"runs", "outcomes", "best", "maps", "agreement"}
    assert list(out["outcomes"]) == ["completed", "no-motion", "aborted", "failed", "claimed", "planned"]
    assert set(out["best"]) >= {"params", "rms"}
    assert all(p.endswith(".png") for p in out["maps"])


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    assert main(["analyse", str(tmp_path / "nothing-here")]) == 2  # a bad DIR, like inspect's bad file (issue 18)
    assert "nothing-here' does not exist" in capsys.readouterr().err
    d = tmp_path / "c"
    make_campaign(d, gammas=(1.0, 10.0), k_ps=(0.1, 1.0))
    assert main(["analyse", str(d), "--margin", "2"]) == 2
    assert main(["analyse", str(d), "--workers", "0"]) == 2
    shutil.rmtree(d)


def test_one_axis_campaign_gives_a_sweep_plot(tmp_path):
    d = tmp_path / "sweep"
    make_campaign(d, gammas=(1000.0,), k_ps=(0.1, 1.0, 10.0, 100.0, 1000.0))
    summary = analyse(d, workers=1)
    assert [p.rsplit("/", 1)[-1] for p in summary["maps"]] == ["sweep.png"]
    assert (
        summary["outcomes"]["aborted"] == 1 and summary["outcomes"]["no-motion"] == 1
    )  # k_p = 1000 > γ/2; γ/k_p = 10⁴ > 1000
