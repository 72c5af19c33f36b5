"""``labrunner run --live``: a Foxglove client (the Foxglove WebSocket protocol, spoken here with
the ``websockets`` package, not the SDK that serves it) watches a real campaign in a
subprocess; what it decodes must agree with the ledger and the logs the campaign wrote. A second
client subscribes and never reads: the campaign must end all the same."""

from __future__ import annotations

import functools
import json
import struct
import threading
import time

import numpy as np
import pytest
from test_campaign_support import campaign_text, ledger_rows, spawn, write
from websockets.sync import client as websockets_sync

from labrunner.campaign.live_view import MAX_SAMPLES, SCHEMAS, parse_address
from labrunner.errors import InvalidParameter
from labrunner.logs import read_run

# foxglove-sdk 0.30 accepts only the protocol's current name (HTTP 400 "Missing expected
# sec-websocket-protocol header" for foxglove.websocket.v1 alone); the frames are the same.
SUBPROTOCOL = "foxglove.sdk.v1"
OFFERED = [SUBPROTOCOL, "foxglove.websocket.v1"]
GRID = '"controller.gamma" = { log10 = [1.5, 3.0], num = 10 }\n"controller.k_p" = { log10 = [0.0, 2.0], num = 12 }'


def _live_url(process, timeout: float = 60.0) -> str:
    """The address from the ``live: ws://HOST:PORT`` line the runner prints as it starts."""
    end = time.monotonic() + timeout
    seen = []
    while time.monotonic() < end:
        line = process.stderr.readline()
        if not line:
            break
        seen.append(line)
        if line.startswith("live: ws://"):
            return line.split()[1]
    raise AssertionError(f"no 'live: ws://' line; stderr began: {''.join(seen)!r}")


def _subscribe(ws, topics: set[str]) -> dict[int, str]:
    """Read the server's serverInfo and advertise messages, subscribe to ``topics``; subscription id → topic."""
    info = json.loads(ws.recv(timeout=20))
    assert info["op"] == "serverInfo"
    channels: dict[str, dict] = {}
    while not topics <= channels.keys():
        message = json.loads(ws.recv(timeout=20))
        if message["op"] == "advertise":
            channels.update({c["topic"]: c for c in message["channels"]})
    for topic in topics:  # JSON messages with JSON schemas: what Plot, Table and Raw Message panels read
        assert channels[topic]["encoding"] == "json" and channels[topic]["schemaEncoding"] == "jsonschema"
        assert json.loads(channels[topic]["schema"]) == SCHEMAS[topic]
    subscriptions = {i: topic for i, topic in enumerate(sorted(topics), start=1)}
    ws.send(
        json.dumps(
            {
                "op": "subscribe",
                "subscriptions": [{"id": i, "channelId": channels[t]["id"]} for i, t in subscriptions.items()],
            }
        )
    )
    return subscriptions


def _decode(frame: bytes, subscriptions: dict[int, str]) -> tuple[str, dict]:
    """A binary Message Data frame: opcode 1, uint32 subscription id, uint64 log time [ns], JSON payload."""
    opcode, sub, _ = struct.unpack_from("<BIQ", frame)
    assert opcode == 1
    return subscriptions[sub], json.loads(frame[13:])


@pytest.mark.slow
def test_a_foxglove_client_sees_progress_runs_and_signals_that_agree_with_the_ledger_and_logs(project):
    write(project / "live.toml", campaign_text(name="live", grid=GRID, duration=2.0))
    process = spawn("run", "live.toml", "--workers", "1", "--batch-size", "6", "--live", "127.0.0.1:0", cwd=project)
    received: dict[str, list[dict]] = {topic: [] for topic in SCHEMAS}
    try:
        url = _live_url(process)
        assert url.startswith("ws://127.0.0.1:") and not url.endswith(":0")
        connect = functools.partial(websockets_sync.connect, url, subprotocols=OFFERED, open_timeout=20)
        with connect() as reader, connect(max_queue=1) as stalled:
            assert reader.subprotocol == SUBPROTOCOL
            subscriptions = _subscribe(reader, set(SCHEMAS))
            _subscribe(stalled, set(SCHEMAS))  # …and never read again: its socket fills, the server must drop for it
            stderr = []
            threading.Thread(target=lambda: stderr.extend(process.stderr), daemon=True).start()
            while True:  # until the runner ends and its server closes the connection
                try:
                    frame = reader.recv(timeout=90)
                except Exception:  # ConnectionClosed at the end of the session
                    break
                if isinstance(frame, bytes):
                    topic, message = _decode(frame, subscriptions)
                    received[topic].append(message)
            assert process.wait(timeout=90) == 0, "".join(stderr)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    rows = {r["id"]: r for r in ledger_rows(project / "data" / "live")}
    assert len(rows) == 120

    runs = received["/campaign/run"]
    assert len(runs) >= 30  # the campaign was still running when the client subscribed
    for run in runs:  # each finished run's outcome, parameters and metrics, as the ledger has them
        row = rows[run["point_id"]]
        assert run["outcome"] == row["outcome"]
        assert run["parameters"] == json.loads(row["parameters"])
        assert run["metrics"]["rms_error"] == pytest.approx(row["rms_error"], rel=1e-12)
        assert run["metrics"]["input_energy"] == pytest.approx(row["input_energy"], rel=1e-12)
    assert received["/campaign/last_runs"][-1]["runs"][0] == runs[-1]  # the newest first

    progress = received["/campaign/progress"]
    assert progress, "no progress message"
    finished = [p["finished"] for p in progress]
    assert finished == sorted(finished) and all(p["total"] == 120 for p in progress)
    for p in progress:
        assert p["finished"] == p["completed"] + p["no_motion"] + p["aborted"] + p["failed"]

    signals = received["/run/signals"]
    assert signals, "no signals message"
    for message in signals[-3:]:  # the representative run's signals, full rate (400 samples), as logged
        log = read_run(project / "data" / "live" / "runs" / f"{message['point_id']}.mcap")
        assert message["decimation"] == 1 and message["rate_hz"] == 200.0
        assert message["names"] == {"output": "omega", "reference": "ref_omega", "error": "e_omega", "input": "u"}
        np.testing.assert_array_equal(message["t"], log.t)
        for role, name in message["names"].items():
            np.testing.assert_array_equal(message[role], log.signal(name))
            np.testing.assert_array_equal(message["signals"][name], log.signal(name))
        assert message["outcome"] == rows[message["point_id"]]["outcome"]


def test_nothing_listens_without_the_flag_and_other_hosts_need_expose():
    assert parse_address("") == parse_address("8765") == parse_address("127.0.0.1:8765")
    assert parse_address("[::1]:0").host == "::1"
    assert parse_address("0.0.0.0:9000", expose=True).expose
    for bad in ("70000", "host:", "a:b"):
        with pytest.raises(InvalidParameter, match="--live: must be a port 0-65535"):
            parse_address(bad)
    with pytest.raises(InvalidParameter, match="not a loopback address.*--live-expose"):
        parse_address("0.0.0.0:9000")


def test_a_long_run_is_decimated_and_says_to_what_rate(tmp_path):
    from labrunner.campaign.live_view import signals_message
    from labrunner.logs import write_run

    n = 5 * MAX_SAMPLES + 1
    signals = {"y": np.arange(n, dtype=float), "u": np.full(n, np.nan), "ref_y": np.zeros(n), "e_y": np.ones(n)}
    path = tmp_path / "run.mcap"
    write_run(
        path,
        metadata={"run": {"point_id": "p"}, "metrics": {"rms_error": float("nan")}, "parameters": {}},
        signals=signals,
        outcome={"status": "completed"},
        fs=1000.0,
        channels={"outputs": ["y"], "references": ["ref_y"], "errors": ["e_y"], "inputs": ["u"], "units": {}},
    )
    message = signals_message(path, "p", {"k_p": 1.0})
    assert message["decimation"] == 6 and message["rate_hz"] == pytest.approx(1000.0 / 6)
    assert message["output"] == list(np.arange(0, n, 6, dtype=float))
    assert message["input"] == [None] * len(message["output"])  # NaN is not JSON
    assert message["metrics"] == {"rms_error": None}
    json.dumps(message, allow_nan=False)
