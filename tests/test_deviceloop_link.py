"""Device loop across processes, over python-can ``udp_multicast`` and over a pty: the emulated
device (``labrunner emulate``) in its own process runs the point; the outcome equals the twin engine's and the signals
and metrics agree within float32 effects; faults on the link are detected and healed."""

from __future__ import annotations

import contextlib
import json
import random
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.device import description
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import linkload
from tests.deviceloop_points import POINTS, assert_same_as_twin

ROOT = Path(__file__).resolve().parent.parent
DEVICE = {"dcmotor-sim": "dcmotor", "valve-sim": "valve", "plate-sim": "plate"}


def rig_file(name: str, medium: str, port: str = "") -> dict:
    """A remote rig file for the device of point ``name`` on ``medium`` (can | canfd | serial)."""
    _, rig_name, _, _, safety = POINTS[name]
    parameters = {"device": DEVICE[rig_name], "node_id": 9, "loop": "device", "model": {}}
    if medium == "serial":
        parameters.update(port=port, baudrate=3_000_000)
    else:
        parameters.update(
            interface="udp_multicast",
            channel="239.74.163.2",
            port=random.randint(20000, 60000),
            bitrate=1_000_000,
            fd=medium == "canfd",
            data_bitrate=5_000_000,
        )
    return {
        "rig": {"kind": "serial" if medium == "serial" else "can", "name": f"{DEVICE[rig_name]}-{medium}"},
        "parameters": parameters,
        "safety": dict(safety),
    }


def rig_toml(config: dict) -> str:
    """``config`` (a rig file as a dict: rig, parameters, safety) as TOML."""
    lines = [f'[rig]\nkind = "{config["rig"]["kind"]}"\nname = "{config["rig"]["name"]}"\n[parameters]']
    lines += [f"{k} = {json.dumps(v)}" for k, v in config["parameters"].items() if k != "model"]
    lines.append("[safety]")
    for key, value in config["safety"].items():
        if isinstance(value, dict):
            lines.append(f"{key} = {{ " + ", ".join(f"{s} = {json.dumps(v)}" for s, v in value.items()) + " }")
        else:
            lines.append(f"{key} = {json.dumps(value)}")
    return "\n".join(lines) + "\n"  # JSON scalars are TOML scalars


@contextlib.contextmanager
def emulator_process(config: dict, faults: tuple[str, ...] = ()):
    """``labrunner emulate --free-run`` of ``config`` in a child process (``faults``: its fault
    options); yields the host's rig file (a pty's name filled in)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{config['rig']['name']}.toml"
        path.write_text(rig_toml(config))
        proc = subprocess.Popen(
            [sys.executable, "-m", "labrunner", "emulate", str(path), "--free-run", *faults],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        try:
            line = proc.stdout.readline().strip()
            if line.startswith("port "):
                config = {**config, "parameters": {**config["parameters"], "port": line.removeprefix("port ")}}
                line = proc.stdout.readline().strip()
            assert line.startswith("serving"), f"emulator did not start: {line!r}"
            yield config
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=10)


def device_run(name: str, config: dict, seed: int = 11):
    point, _, fs, duration, safety = POINTS[name]
    rig = load_rig(config_from_dict(config))
    with rig:
        [result] = rig.run_on_device([point], fs=fs, duration=duration, seeds=[seed], rig_safety=safety)
    return result


CASES = [
    ("motor-mfc2", "can"),
    ("motor-aborted", "can"),
    ("valve-mfc1", "can"),
    ("plate-mfc", "canfd"),
    ("motor-mfc1", "serial"),
    ("valve-mfc1", "serial"),
    ("plate-mbc", "serial"),
]


@pytest.mark.slow
@pytest.mark.parametrize("name, medium", CASES)
def test_device_loop_across_processes_gives_the_twin_result(name, medium):
    with emulator_process(rig_file(name, medium)) as config:
        result = device_run(name, config)
    assert_same_as_twin(result, name, 11)
    d = result.diagnostics
    assert d["loop"] == "device" and d["device_loop"]["ticks"] == result.n_samples and d["device_loop"]["overruns"] == 0
    assert d["law_check"]["flag"] == "ok", d["law_check"]  # the host's reference-law check (docs/control-laws.md)
    assert d["device_loop"]["device_run_s"] == pytest.approx(result.n_samples / result.fs)
    assert d["device_loop"]["bytes_to_host"] >= result.n_samples * 4 * len(result.channels["inputs"])
    link = linkload.from_rig(config["rig"]["kind"], config["parameters"])
    fits = linkload.device_loop_load(link, result.fs, d["device_loop"]["columns"]) <= linkload.MAX_LOAD
    assert d["device_loop"]["streamed"] == fits and fits == (
        name.startswith("motor") or name == "valve-mfc1" and medium == "serial"
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "medium, faults",
    [("can", ("--drop", "0.004", "--seed", "2")), ("serial", ("--drop", "0.003", "--garbage", "0.01", "--seed", "3"))],
)
def test_lost_and_corrupted_frames_are_detected_and_resent(medium, faults):
    with emulator_process(rig_file("valve-mfc1", medium), faults) as config:
        result = device_run("valve-mfc1", config)
    assert_same_as_twin(result, "valve-mfc1", 11)
    received = result.diagnostics["device_loop"]["received"]
    assert received["broken"] + received["crc_errors"] > 0 and received["nacks"] > 0


@pytest.mark.slow
def test_a_host_loop_rig_file_is_not_run_on_the_device():
    config = rig_file("motor-mfc1", "can")
    config["parameters"]["loop"] = "host"
    with emulator_process(config) as config:
        rig = load_rig(config_from_dict(config))
        with rig:
            assert rig.loop == "host"


@pytest.mark.slow
def test_a_rig_file_asking_for_reference_tables_runs_the_twin_result_across_processes():
    config = rig_file("motor-mfc2", "can")
    config["parameters"]["reference_table"] = True
    with emulator_process(config) as config:
        result = device_run("motor-mfc2", config)
    assert_same_as_twin(result, "motor-mfc2", 11)
    point, rig_name, fs, duration, safety = POINTS["motor-mfc2"]
    compact = description.build(point, load_rig(rig_name).info, fs=fs, duration=duration, seed=11, rig_safety=safety)
    assert result.diagnostics["device_loop"]["description_bytes"] > len(compact) + 32 * 200  # ≥ 1 s of table rows
