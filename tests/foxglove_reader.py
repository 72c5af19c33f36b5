"""What the official TypeScript MCAP reader (@mcap/core, the Foxglove app's) and the official Python
reader (``mcap``, payloads decoded by protobuf classes built from the file's schema) read from a run
log, checked against labrunner's reader (no tests here).

``tests/js/read_log.js`` prints what @mcap/core's ``McapIndexedReader`` and ``McapStreamReader``
decode (payloads decoded by protobufjs from the file's own schema, as Foxglove does); it needs
``npm ci --prefix tests/js``. Without node or its packages the tests skip, and fail when
``LABRUNNER_CI=1`` (the CI must run them).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Metadata
from mcap.stream_reader import StreamReader
from test_logs import classes_from_file

from labrunner.logs import BLOCK_TOPIC, SAMPLES_TOPIC, RunLog, read_run
from labrunner.logs.schema import sample_fields

JS = Path(__file__).parent / "js"
_SPECIAL = {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf, "-0": -0.0}


def node_command() -> list[str]:
    """``node read_log.js``, or skip (fail under LABRUNNER_CI=1) when node or @mcap/core is missing."""
    node = shutil.which("node")
    missing = (
        "node is not installed"
        if node is None
        else "tests/js/node_modules lacks @mcap/core (run `npm ci --prefix tests/js`)"
        if not (JS / "node_modules" / "@mcap" / "core").is_dir()
        else ""
    )
    if missing:
        if os.environ.get("LABRUNNER_CI") == "1":
            pytest.fail(f"the TypeScript MCAP reader cannot run: {missing}")
        pytest.skip(missing)
    return [node, str(JS / "read_log.js")]


def read_with_mcap_core(path: Path) -> dict:
    """The JSON ``read_log.js`` prints for ``path``: {"indexed": ..., "stream": ...}."""
    done = subprocess.run([*node_command(), str(path)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def _number(value: float | str) -> float:
    return _SPECIAL[value] if isinstance(value, str) else float(value)


def assert_same_bits(got: np.ndarray, expected: np.ndarray, what: str) -> None:
    """Equal float64 bit for bit; NaN matches NaN (JavaScript keeps no NaN payload)."""
    got, expected = np.asarray(got, dtype=np.float64), np.asarray(expected, dtype=np.float64)
    assert got.shape == expected.shape, f"{what}: {got.shape} values, expected {expected.shape}"
    nan = np.isnan(expected)
    assert np.array_equal(np.isnan(got), nan), f"{what}: NaN at other samples"
    assert np.array_equal(got[~nan].view(np.uint64), expected[~nan].view(np.uint64)), f"{what}: values differ"


def stored_records(path: Path) -> tuple[dict[str, dict[str, str]], int]:
    """Every metadata record as stored (strings), and ``/run/samples``' decimation (its channel's
    metadata), through the official Python stream reader (up to the cut of a torn file)."""
    metadata, decimation = {}, 1
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, emit_chunks=True).records:
                if isinstance(record, Metadata):
                    metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Channel) and record.topic == SAMPLES_TOPIC:
                    decimation = int(record.metadata["decimation"])
        except (McapError, EOFError, ValueError):  # a torn file's end
            pass
    return metadata, decimation


def _official_python(path: Path, log: RunLog, fields: list[str], step: int, old_samples: bool) -> Counter:
    """(topic, sequence, log time) of every message through ``mcap``'s seeking reader, its
    ``/run/samples`` payloads decoded by protobuf classes built from the file's own schema and
    checked against labrunner's reading bit for bit."""
    classes = classes_from_file(path)
    seen: Counter = Counter()
    values: dict[str, list[float]] = {field: [] for field in fields}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=True):
            seen[(channel.topic, message.sequence, message.log_time)] += 1
            if channel.topic == SAMPLES_TOPIC and not old_samples:
                decoded = classes[schema.name].FromString(message.data)
                for field in fields:
                    values[field].append(getattr(decoded, field))
    for j, field in enumerate(fields if not old_samples else ()):
        assert_same_bits(np.array(values[field]), log.data[j, ::step], f"mcap (Python) {field}")
    return seen


def check_log(path: Path) -> RunLog:
    """Assert that @mcap/core's two readers (and, for a finished file, ``mcap``'s) read every
    message of the log at ``path`` once, with the metadata and the very values labrunner's reader
    gives; a torn file (no summary) is read by the stream reader up to its cut, the indexed reader
    refusing it. Returns labrunner's reading."""
    log = read_run(path)
    out = read_with_mcap_core(path)
    metadata, step = stored_records(path)
    units = [str(log.channels[name].get("unit") or "") for name in log.names]
    fields = sample_fields(list(log.names), units)
    # labrunner-2 logs numbered their samples by message, with a time field: their blocks hold the values
    old_samples = log.metadata["run"].get("log_format") == "labrunner-2"
    seen = []
    for which in ("indexed", "stream"):
        got = out[which]
        if log.torn and which == "indexed":
            assert "error" in got, "the indexed reader read a file without a summary"
            continue
        assert "error" not in got, f"{which}: {got.get('error')}"
        assert got["complete"] is not log.torn
        assert got["metadata"] == metadata, which
        samples = got["messages"].get(SAMPLES_TOPIC, [])
        blocks = got["messages"].get(BLOCK_TOPIC, [])
        assert set(got["messages"]) <= {SAMPLES_TOPIC, BLOCK_TOPIC}
        if not old_samples:
            k = [s[0] for s in samples]
            assert k == list(range(0, log.n_samples, step)), f"{which}: sample indexes"
            times = np.array([int(s[1]) for s in samples], dtype=np.int64)
            assert np.array_equal(np.diff(times), np.diff(np.rint(np.array(k) * (1e9 / log.fs)).astype(np.int64)))
            for j, field in enumerate(fields):
                values = np.array([_number(s[2][field]) for s in samples])
                assert_same_bits(values, log.data[j, ::step], f"{which} {field}")
        if blocks:
            full = {name: [] for name in log.names}
            for _, _, block in sorted(blocks, key=lambda b: int(b[2]["first_index"])):
                for signal in block["signals"]:
                    full[signal["name"]] += [_number(v) for v in signal["values"]]
            for j, name in enumerate(log.names):
                assert_same_bits(np.array(full[name]), log.data[j], f"{which} {BLOCK_TOPIC} {name}")
        for topic, (forwards, backwards) in got.get("byTopic", {}).items():  # a panel's read of one topic
            assert forwards == backwards == [row[0] for row in got["messages"][topic]], f"{which} {topic} alone"
        seen.append(Counter((topic, row[0], int(row[1])) for topic, rows in got["messages"].items() for row in rows))
    assert all(max(c.values(), default=1) == 1 for c in seen), "a message read twice"
    if not log.torn:
        assert seen[0] == seen[1] == _official_python(path, log, fields, step, old_samples)
    return log
