"""Issue 34: every kind of log labrunner writes opens in Foxglove — @mcap/core's McapIndexedReader
and McapStreamReader (tests/js/read_log.js) and the official Python reader read every message
once, with the values labrunner's reader gives, bit for bit (:mod:`foxglove_reader`).

Kinds: motor, valve and plate twins through ``labrunner run`` (completed and aborted runs), a
campaign thinned by ``[logging] samples_hz``, a motor campaign whose loop runs on the emulated
device, a streamed run that failed, a streamed run killed mid-run (torn: the stream reader reads
it up to the cut, as labrunner salvages it), the logs ``resume`` accepts and quarantines after a
runner's crash, and the labrunner-2 log kept as a fixture."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from foxglove_reader import check_log, read_with_mcap_core
from test_campaign_support import campaign_text, write
from test_logs_salvage import WRITER

from labrunner.cli import main
from labrunner.logs import RunLogWriter
from tests.test_deviceloop_link import emulator_process, rig_file, rig_toml

# k_p = 3000 1/s drives the motor past its safety bounds: an aborted run beside a completed one
MOTOR_GRID = '"controller.k_p" = { values = [50.0, 3000.0] }'
_DIFFERENTIATOR = """[differentiator]
alpha = 2
beta = 2
N = 0
omega_c = 250.0
method = "midpoint"
"""
VALVE = f"""[campaign]
name = "valve"
rig = "valve-sim"
fs = 4000.0
duration = 0.5
seed = 1

[controller]
kind = "mfc1"
output = "flow"
gamma = 0.4
k_p = 30.0
i_min = 0.5

{_DIFFERENTIATOR}
[reference]
kind = "setpoints"
levels = [1.0, 5.0, 1.0]
transition = 0.1
hold = 0.1

[grid]
"controller.k_p" = {{ values = [30.0, 3000.0] }}
"""
PLATE = """[campaign]
name = "plate"
rig = "plate-sim"
fs = 32000.0
duration = 0.08
seed = 2

[controller]
kind = "plate-mfc"
input = "v"
gamma = 1.0
k_p = 5000.0
k_d = 195.0

[differentiator]
alpha = 4
beta = 4
N = 0
omega_c = 840.0
method = "midpoint"

[reference]
kind = "lift"
lift = 0.1
settle = 0.02
transition = 0.05
hold = 0.02

[grid]
"differentiator.omega_c" = { values = [640.0, 840.0] }
"""


def _campaign(project: Path, text: str) -> list[Path]:
    path = write(project / "c.toml", text)
    assert main(["run", str(path), "--out", str(project / "out")]) == 0
    logs = sorted((project / "out" / "runs").glob("*.mcap"))
    assert logs
    return logs


def _statuses(logs: list[Path]) -> set[str]:
    return {check_log(path).outcome["status"] for path in logs}


def test_motor_logs_completed_and_aborted(project):
    logs = _campaign(project, campaign_text("motor", grid=MOTOR_GRID, duration=1.5))
    assert _statuses(logs) == {"completed", "aborted"}


def test_motor_logs_thinned_by_samples_hz(project):
    text = campaign_text("thin", grid=MOTOR_GRID, duration=1.5, extra="[logging]\nsamples_hz = 40.0\n")
    logs = _campaign(project, text)
    assert _statuses(logs) == {"completed", "aborted"}
    assert all(check_log(path).metadata["run"]["samples"].startswith("every 5th") for path in logs)


def test_valve_logs(project):
    assert "completed" in _statuses(_campaign(project, VALVE))


def test_plate_logs(project):
    assert _statuses(_campaign(project, PLATE)) <= {"completed", "aborted"}


@pytest.mark.slow
def test_device_loop_logs(project):
    """The motor's loop on the emulated device (over a pty), its samples float32 as the device's."""
    with emulator_process(rig_file("motor-mfc1", "serial")) as config:
        write(project / "rigs" / "device.toml", rig_toml(config))
        text = campaign_text("device", rig="rigs/device.toml", grid=MOTOR_GRID, duration=1.0)
        logs = _campaign(project, text)
    for path in logs:
        log = check_log(path)
        assert log.metadata["diagnostics"]["loop"] == "device"


def test_a_failed_streamed_run(tmp_path):
    """A real rig's run cut by an exception: the writer closes the file with outcome ``failed``."""
    path = tmp_path / "failed.mcap"
    k = np.arange(300.0)
    with pytest.raises(RuntimeError), RunLogWriter(path, metadata={}, fs=100.0, channels=["y", "u"]) as w:
        w.write_block(0, {"y": np.sin(k), "u": np.where(k == 7, np.nan, -k * 0.0)})
        raise RuntimeError("link lost")
    log = check_log(path)
    assert log.outcome["status"] == "failed" and log.n_samples == 300


def test_a_run_killed_mid_write(tmp_path):
    """SIGKILLed while streaming: the stream reader (Foxglove opens a file without a summary so)
    reads every flushed sample, as labrunner salvages them; the indexed reader refuses it."""
    path = tmp_path / "killed.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        for _ in range(4):
            proc.stdout.readline()
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    log = check_log(path)
    assert log.torn and log.n_samples >= 4 * 250


def test_the_labrunner_2_fixture_log():
    check_log(Path(__file__).parent / "data" / "log-format-labrunner-2.mcap")


def test_a_labrunner_3_log_is_refused_by_the_indexed_reader(tmp_path):
    """The regression itself: the old layout, which the indexed reader refuses (why logs are upgraded)."""
    from labrunner.logs import write_run
    from labrunner.logs.writer import LogPrefix

    path = tmp_path / "old.mcap"
    prefix = LogPrefix(fs=100.0, channels=["y"], log_format="labrunner-3")
    write_run(path, metadata={}, signals={"y": np.arange(50.0)}, outcome={"status": "completed"}, prefix=prefix)
    out = read_with_mcap_core(path)
    assert "chunk index without message indexes" in out["indexed"]["error"]
    assert len(out["stream"]["messages"]["/run/samples"]) == 50


def test_logs_recovered_after_a_crash(project):
    """A runner that died after a worker published a log and before it committed the row, while
    another log was half written: ``resume`` accepts the first (``recovered``) and quarantines the
    second; both open, the torn one by the stream reader up to its cut."""
    logs = _campaign(project, campaign_text("crash", grid=MOTOR_GRID, duration=1.5))
    directory = project / "out"
    published, other = logs
    torn = directory / "runs" / f".tmp-{other.stem}-999-x.mcap"
    torn.write_bytes(other.read_bytes()[: other.stat().st_size * 2 // 3])
    db = sqlite3.connect(directory / "ledger.sqlite")
    with db:
        db.execute("UPDATE points SET state = 'claimed' WHERE id = ?", (published.stem,))
    db.close()
    assert main(["resume", str(directory)]) == 0
    db = sqlite3.connect(directory / "ledger.sqlite")
    (outcome,) = db.execute("SELECT outcome_json FROM points WHERE id = ?", (published.stem,)).fetchone()
    (moved,) = db.execute("SELECT moved_to FROM quarantine").fetchone()
    db.close()
    assert json.loads(outcome)["recovered"] is True
    check_log(published)
    assert check_log(directory / moved).torn


def test_without_the_typescript_reader_ci_fails_and_a_laptop_skips(tmp_path, monkeypatch):
    """No node_modules (``npm ci --prefix tests/js`` not run): under LABRUNNER_CI=1 the tests fail,
    elsewhere they skip."""
    import foxglove_reader

    monkeypatch.setattr(foxglove_reader, "JS", tmp_path)
    monkeypatch.setenv("LABRUNNER_CI", "1")
    with pytest.raises(pytest.fail.Exception, match="npm ci --prefix tests/js"):
        foxglove_reader.node_command()
    monkeypatch.delenv("LABRUNNER_CI")
    with pytest.raises(pytest.skip.Exception):
        foxglove_reader.node_command()
