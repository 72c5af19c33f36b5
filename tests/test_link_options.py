"""``check-rig`` and ``conform`` take the link on the command line (issue 36: ``emulate`` printed a
pty while ``check-rig`` opened the rig file's /dev/ttyACM0, and a user had to copy and edit the file)."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from labrunner.errors import InvalidParameter
from labrunner.rigs.config import load_rig_config

ROOT = Path(__file__).resolve().parents[1]
SERIAL = ROOT / "rigs" / "dcmotor-serial.toml"
CAN = ROOT / "rigs" / "dcmotor-can.toml"


def test_the_link_options_replace_the_files_and_are_validated_like_it():
    assert load_rig_config(SERIAL).parameters["port"] == "/dev/ttyACM0"
    assert load_rig_config(SERIAL, link={"port": "/dev/pts/7", "interface": None}).parameters["port"] == "/dev/pts/7"
    can = load_rig_config(CAN, link={"interface": "udp_multicast", "channel": "239.74.163.2"})
    assert (can.parameters["interface"], can.parameters["channel"]) == ("udp_multicast", "239.74.163.2")
    with pytest.raises(InvalidParameter, match=r"--channel: applies to a can rig; .* is a 'serial' rig"):
        load_rig_config(SERIAL, link={"channel": "can0"})
    with pytest.raises(InvalidParameter, match=r"--port: applies to a serial rig; .* is a 'can' rig"):
        load_rig_config(CAN, link={"port": "/dev/pts/7"})


def test_check_rig_reaches_the_emulators_pty_given_on_the_command_line(tmp_path):
    emulator = subprocess.Popen(
        [sys.executable, "-m", "labrunner", "emulate", str(SERIAL)], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    env = {**os.environ, "LABRUNNER_CACHE": str(tmp_path)}
    try:
        first = emulator.stdout.readline().split()
        assert first[0] == "port", first
        port = first[1]
        cmd = [sys.executable, "-m", "labrunner", "check-rig", str(SERIAL), "--port", port, "--pings", "20", "--json"]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
        assert out.returncode == 0, out.stderr
        report = json.loads(out.stdout)  # a handshake and round trips with the emulator on its pty
        kept = json.loads((tmp_path / "check-rig.json").read_text())  # what run will compare f_s with
        [(key, entry)] = kept.items()
        assert json.loads(key) == [str(SERIAL), {"port": port}] and entry["max_host_fs"] == report["max_host_fs"]
        without = subprocess.run(cmd[:5] + cmd[7:], capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
        assert without.returncode != 0 and "/dev/ttyACM0" in without.stderr  # the file's port: no board here
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=10)


def test_emulate_and_check_rig_share_a_can_channel_given_on_the_command_line():
    link = ["--interface", "udp_multicast", "--channel", "239.74.163.77"]
    emulator = subprocess.Popen(
        [sys.executable, "-m", "labrunner", "emulate", str(CAN), *link], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    try:
        assert emulator.stdout.readline().startswith("serving")
        cmd = [sys.executable, "-m", "labrunner", "check-rig", str(CAN), *link, "--pings", "20", "--json"]
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout)
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=10)


def test_run_warns_before_a_campaign_faster_than_check_rig_last_measured(project, monkeypatch, capsys):
    from test_campaign_support import campaign_text, write

    from labrunner.cli import main
    from labrunner.rigs.transports import link_record

    monkeypatch.setenv("LABRUNNER_CACHE", str(project / "cache"))
    rig = write(project / "rigs" / "bench.toml", SERIAL.read_text())
    campaign = write(project / "c.toml", campaign_text(name="c", rig="rigs/bench.toml"))  # f_s = 200 Hz
    config = load_rig_config(rig)
    key = link_record.link_key(rig, config.kind, config.parameters)
    assert link_record.last(key) is None
    (project / "cache").mkdir()
    link_record.record_path().write_text("{not json")  # a damaged record is no record
    assert link_record.last(key) is None and link_record.warning(key, 200.0) == ""
    link_record.remember(key, 86.0)
    assert link_record.last(key)["max_host_fs"] == 86.0
    other = link_record.link_key(rig, config.kind, {**config.parameters, "port": "/dev/pts/9"})
    assert link_record.last(other) is None  # another link, another measurement
    capsys.readouterr()
    assert main(["run", str(campaign), "--dry-run"]) == 0
    assert "warning: f_s = 200 Hz exceeds the 86 Hz the host loop sustained on this link" in capsys.readouterr().out
    link_record.remember(key, 500.0)
    assert main(["run", str(campaign), "--dry-run"]) == 0
    assert "warning" not in capsys.readouterr().out


def test_run_takes_the_port_on_the_command_line_and_keeps_it_for_resume(project):
    from test_campaign_support import campaign_text, cli, ledger_rows, write

    write(project / "rigs" / "bench.toml", SERIAL.read_text())
    grid = '"controller.k_p" = { values = [10.0, 20.0] }'
    write(project / "c.toml", campaign_text(name="c", rig="rigs/bench.toml", duration=0.5, grid=grid))
    emulator = subprocess.Popen(
        [sys.executable, "-m", "labrunner", "emulate", str(project / "rigs" / "bench.toml")],
        stdout=subprocess.PIPE,
        text=True,
        cwd=project,
    )
    try:
        port = emulator.stdout.readline().split()[1]
        out = cli("run", "c.toml", "--port", port, cwd=project)
        assert out.returncode == 0, out.stderr
        rows = ledger_rows(project / "data" / "c")
        # reached the device: a rig that cannot be opened stops the campaign (exit 1, points claimed);
        # a run that then fails on a loaded machine (late frames: the emulator is not paced here) is terminal
        assert len(rows) == 2 and {r["state"] for r in rows} <= {"done", "aborted", "failed"}
        with sqlite3.connect(project / "data" / "c" / "ledger.sqlite") as db:
            kept = db.execute("SELECT value FROM meta WHERE key = 'rig_link'").fetchone()[0]
        assert json.loads(kept) == {"port": port}  # resume reaches the same device without --port
        assert cli("resume", "data/c", cwd=project).returncode == 0
        without = cli("run", "c.toml", "--out", "data/d", cwd=project)  # the rig file's /dev/ttyACM0: no board
        assert without.returncode == 1 and "/dev/ttyACM0" in without.stderr, without.stderr
    finally:
        emulator.send_signal(signal.SIGINT)
        emulator.wait(timeout=10)
