"""What a user sees of a campaign, checked with third-party tools on a real (simulated) campaign:
the logs through the official ``mcap`` reader and protobuf classes built from the file's own
schemas, the metrics table through pandas, the report's links through an HTML parser, and the
words ``run``, ``status``, ``analyse`` and the report count with."""

from __future__ import annotations

import contextlib
import html.parser
import io
import re
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from test_campaign_support import MOTOR_RIG, campaign_text, write
from test_logs import classes_from_file

from labrunner.cli import main
from labrunner.logs import SAMPLES_TOPIC, read_run

GRID = '"controller.gamma" = { log10 = [0.0, 4.0], num = 4 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 4 }'
COUNTS = re.compile(r"\d+ completed, \d+ no-motion, \d+ aborted, \d+ failed")


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """A 4 × 4 γ–k_p campaign on the motor twin (early aborts at small γ), run, then analysed
    with the aborted runs plotted; the text each command printed."""
    root = tmp_path_factory.mktemp("project")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(root / "rigs" / "motor.toml", MOTOR_RIG)
    path = write(root / "campaigns" / "words.toml", campaign_text("words", duration=3.0, grid=GRID))
    directory = root / "data" / "words"
    printed = {}
    started = time.time()
    for name, args in (
        ("run", ["run", str(path), "--out", str(directory), "--workers", "1"]),
        ("status", ["status", str(directory)]),
        ("analyse", ["analyse", str(directory), "--workers", "1", "--plot", "aborted"]),
    ):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            assert main(args) == 0, err.getvalue()
        printed[name] = out.getvalue()
        printed[name + " progress"] = err.getvalue()
    return directory, printed, started


def test_words_are_the_same_in_run_status_analyse_and_report(campaign):
    directory, printed, _ = campaign
    report = (directory / "report" / "index.html").read_text(encoding="utf-8")
    found = {
        name: COUNTS.findall(text)
        for name, text in (
            ("run", printed["run"]),
            ("status", printed["status"]),
            ("analyse", printed["analyse"]),
            ("report", report),
        )
    }
    assert all(found.values()), found
    assert len({hits[0] for hits in found.values()}) == 1, found  # one count, in one wording
    table = pd.read_csv(directory / "report" / "metrics.csv")
    counts = table["outcome"].value_counts()
    assert found["run"][0] == ", ".join(
        f"{counts.get(w, 0)} {w}" for w in ("completed", "no-motion", "aborted", "failed")
    )
    for text in (printed["run"], printed["status"], printed["analyse"], printed["run progress"]):
        assert not re.search(r"\bdone\b", text), text  # the ledger's internal state is no outcome word
    assert set(table["outcome"]) <= {"completed", "no-motion", "aborted", "failed", "claimed", "planned"}
    assert COUNTS.search(printed["run progress"].splitlines()[0])  # a progress line before the first run ends


def test_ranking_the_table_by_rms_error_never_picks_an_aborted_run(campaign):
    directory, _, _ = campaign
    table = pd.read_csv(directory / "report" / "metrics.csv")
    aborted = table[table["outcome"] == "aborted"]
    completed = table[table["outcome"] == "completed"]
    # the trap: an aborted run's RMS over its truncated run is below every completed run's
    assert not aborted.empty and aborted["rms_error_until_abort"].min() < completed["rms_error"].min()
    assert table.sort_values("rms_error").iloc[0]["outcome"] == "completed"
    assert table.loc[table["rms_error"].idxmin(), "outcome"] == "completed"
    assert table.nsmallest(5, "rms_error")["outcome"].isin(["completed", "no-motion"]).all()
    assert aborted[["rms_error", "input_energy", "max_abs_input"]].isna().all().all()
    assert table["n_samples"].dtype == np.int64 and table["attempts"].dtype == np.int64


def test_log_paths_resolve_from_the_table_that_holds_them(campaign):
    directory, _, _ = campaign
    report = directory / "report"
    for table in (pd.read_csv(report / "metrics.csv"), pd.read_parquet(report / "metrics.parquet")):
        assert all((report / p).is_file() for p in table["log_path"])


class _Links(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.links: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.links += [v for k, v in attrs if k in ("href", "src") and v and not v.startswith("data:")]


def test_every_link_in_the_report_resolves_to_a_file(campaign):
    directory, _, _ = campaign
    report = directory / "report"
    parser = _Links()
    parser.feed((report / "index.html").read_text(encoding="utf-8"))
    assert parser.links
    assert all((report / link).is_file() for link in parser.links), [
        l for l in parser.links if not (report / l).is_file()
    ]
    table = pd.read_csv(report / "metrics.csv")
    names = {Path(link).name for link in parser.links}
    assert {"metrics.csv", "metrics.parquet", "campaign.toml"} <= names
    assert {f"{i}.mcap" for i in table["id"]} <= names  # every run's log
    assert {f"{i}.png" for i in table.loc[table["outcome"] == "aborted", "id"]} <= names  # the plots asked for


def test_report_table_lists_every_run_and_sorts_offline(campaign):
    directory, _, _ = campaign
    text = (directory / "report" / "index.html").read_text(encoding="utf-8")
    table = pd.read_csv(directory / "report" / "metrics.csv")
    assert 'class="sortable"' in text and "<script>" in text and "http" not in text.split("<script>")[1]
    assert all(f"<td>{i}</td>" in text for i in table["id"])
    assert "Stability bounds used" in text and "(2.46)" in text and "k_p interval" in text
    assert "[campaign]" in text and "name = &quot;words&quot;" in text  # the campaign file, shown


def test_campaign_logs_decode_with_their_own_schemas(campaign):
    """A log as a worker publishes it: per-sample messages at the full rate whose fields name their
    units, equal sample for sample to what read_run gives, sequence = sample index, with absolute,
    increasing log times; the rig record and the campaign file as a viewer shows them."""
    directory, _, started = campaign
    table = pd.read_csv(directory / "report" / "metrics.csv")
    path = directory / "runs" / f"{table.loc[table['outcome'] == 'completed', 'id'].iloc[0]}.mcap"
    classes = classes_from_file(path)
    log = read_run(path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        samples, times, sequences = [], [], []
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert channel.topic == SAMPLES_TOPIC  # each sample stored once: no /run/blocks copy
            samples.append(classes[schema.name].FromString(message.data))
            times.append(message.log_time)
            sequences.append(message.sequence)
        f.seek(0)
        raw = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert len(samples) == log.n_samples == 600  # 3 s at 200 Hz: every sample
    fields = [f.name for f in samples[0].DESCRIPTOR.fields]
    assert "omega__rad_per_s" in fields and "u__V" in fields and sequences == list(range(600))
    for name in log.channels:
        field = next(f for f in fields if f == name or f.startswith(name + "__"))
        assert np.array_equal(
            np.array([getattr(m, field) for m in samples]), log.frame[name].to_numpy(), equal_nan=True
        )
    assert np.all(np.diff(times) > 0) and started - 5 < times[0] / 1e9 < time.time()
    channel = next(c for c in summary.channels.values() if c.topic == SAMPLES_TOPIC)
    assert channel.metadata["unit.omega__rad_per_s"] == "rad/s" and channel.metadata["rate_hz"] == "200.0"
    assert raw["outcome"]["status"] == "completed" and raw["run"]["attempt"] == "1" and "monitor" not in raw["outcome"]
    assert set(raw["rig"]) == {"json"} and log.metadata["rig"]["rig"]["kind"] == "dcmotor"
    assert "motion_output" in log.metadata["rig"]["safety"]


def test_logging_section_thins_the_samples_and_says_so(tmp_path):
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(tmp_path / "rigs" / "motor.toml", MOTOR_RIG)
    grid = '"controller.k_p" = { values = [10.0] }'
    path = write(
        tmp_path / "c.toml", campaign_text("thin", duration=1.0, grid=grid, extra="\n[logging]\nsamples_hz = 50.0\n")
    )
    assert main(["run", str(path), "--out", str(tmp_path / "d")]) == 0
    (log,) = (tmp_path / "d" / "runs").glob("*.mcap")
    with open(log, "rb") as f:
        channel = next(c for c in make_reader(f).get_summary().channels.values() if c.topic == SAMPLES_TOPIC)
    assert channel.metadata["decimation"] == "4" and channel.metadata["rate_hz"] == "50.0"
    assert "every 4th sample" in read_run(log).metadata["run"]["samples"]
    assert read_run(log).n_samples == 200  # thinned: the blocks keep every sample
    bad = write(tmp_path / "bad.toml", campaign_text("bad", grid=grid, extra="\n[logging]\nsamples_hz = -1\n"))
    assert main(["run", str(bad), "--out", str(tmp_path / "e")]) == 2
    assert not (tmp_path / "e").exists()


def test_logging_precision_float32_stores_the_rounding_of_the_same_runs(tmp_path, capsys):
    """``[logging] precision = "float32"``: the same points (same ids), each signal the float32
    rounding of what the default float64 logs hold, metrics untouched (computed before rounding),
    and smaller files; another value is refused naming the key."""
    (tmp_path / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(tmp_path / "rigs" / "motor.toml", MOTOR_RIG)
    grid = '"controller.k_p" = { values = [10.0, 30.0] }'
    exact = write(tmp_path / "a.toml", campaign_text("prec", duration=2.0, grid=grid))
    single = write(
        tmp_path / "b.toml",
        campaign_text("prec", duration=2.0, grid=grid, extra='\n[logging]\nprecision = "float32"\n'),
    )
    assert main(["run", str(exact), "--out", str(tmp_path / "a")]) == 0
    assert main(["run", str(single), "--out", str(tmp_path / "b")]) == 0
    logs = sorted(p.name for p in (tmp_path / "a" / "runs").glob("*.mcap"))
    assert len(logs) == 2 and logs == sorted(p.name for p in (tmp_path / "b" / "runs").glob("*.mcap"))
    for name in logs:
        a, b = read_run(tmp_path / "a" / "runs" / name), read_run(tmp_path / "b" / "runs" / name)
        assert pd.Series(a.metadata["metrics"]).equals(pd.Series(b.metadata["metrics"]))  # NaN == NaN here
        expected = a.data.astype(np.float32).astype(np.float64)
        assert not np.array_equal(a.data, expected, equal_nan=True)  # the rounding is real
        assert np.array_equal(b.data, expected, equal_nan=True) and "float32: " in b.metadata["run"]["samples"]
        assert (tmp_path / "b" / "runs" / name).stat().st_size < 0.8 * (tmp_path / "a" / "runs" / name).stat().st_size
    capsys.readouterr()
    bad = write(tmp_path / "c.toml", campaign_text("c", grid=grid, extra='\n[logging]\nprecision = "half"\n'))
    assert main(["run", str(bad), "--out", str(tmp_path / "c")]) == 2
    assert "logging.precision" in capsys.readouterr().err and not (tmp_path / "c").exists()
