"""Torn run logs: a writer killed mid-run leaves a file whose complete chunks are salvaged."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from mcap.reader import make_reader
from test_logs_support import COMPLETED, metadata

from labrunner.logs import SAMPLES_TOPIC, RunLogWriter, read_metadata, read_outcome, read_run

BLOCK = 250


def ramp(k0: int, n: int) -> dict[str, np.ndarray]:
    """Deterministic signals of samples k0 .. k0 + n - 1, recomputable by the test."""
    k = np.arange(k0, k0 + n, dtype=np.float64)
    return {"y": np.sin(k / 50.0), "u": k, "ref_y": np.cos(k / 50.0)}


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    """A finished file written in blocks of 250 with a flush after each (one chunk of per-sample
    messages per block)."""
    path = tmp_path_factory.mktemp("torn") / "full.mcap"
    with RunLogWriter(
        path,
        metadata=metadata(),
        fs=1000.0,
        channels=["y", "u", "ref_y"],
        attachments={"c.toml": b"x = 1"},
        flush_interval_s=0.0,
    ) as w:
        for b in range(8):
            w.write_block(b * BLOCK, ramp(b * BLOCK, BLOCK))
        w.finish(COMPLETED)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert {c.topic for c in summary.channels.values()} == {SAMPLES_TOPIC}
    chunk_ends = sorted(c.chunk_start_offset + c.chunk_length for c in summary.chunk_indexes)
    outcome = next(m for m in summary.metadata_indexes if m.name == "outcome")
    assert len(chunk_ends) == 8 and len(summary.chunk_indexes) == 8
    assert outcome.offset > max(c.chunk_start_offset for c in summary.chunk_indexes)  # the outcome follows the data
    return path, path.read_bytes(), chunk_ends, outcome.offset + outcome.length


def test_every_cut_keeps_exactly_the_complete_chunks(streamed, tmp_path):
    path, data, chunk_ends, outcome_end = streamed
    first_chunk = chunk_ends[0] - 1
    cuts = sorted(
        {*range(first_chunk - 50, len(data) - 1, 997), *(e for e in chunk_ends), *(e - 1 for e in chunk_ends)}
    )
    expected = ramp(0, 8 * BLOCK)
    for cut in cuts:
        torn = tmp_path / "cut.mcap"
        torn.write_bytes(data[:cut])
        log = read_run(torn)
        assert log.torn, cut
        assert (log.outcome is None) == (cut < outcome_end), cut
        complete = sum(end <= cut for end in chunk_ends)
        assert log.n_samples == complete * BLOCK, cut
        for name, values in expected.items():
            assert np.array_equal(log.frame[name].to_numpy(), values[: log.n_samples]), (cut, name)
        assert log.metadata["run"]["point_id"] == "p-0042" and log.attachments == {"c.toml": b"x = 1"}
        assert log.fs == 1000.0
    torn.write_bytes(data[: chunk_ends[3]])
    assert read_outcome(torn) is None and "config" in read_metadata(torn)


def test_torn_before_first_block_has_metadata_and_no_samples(streamed, tmp_path):
    _, data, chunk_ends, _ = streamed
    torn = tmp_path / "early.mcap"
    torn.write_bytes(data[: chunk_ends[0] - 100])
    log = read_run(torn)
    assert log.torn and log.n_samples == 0 and list(log.frame.columns) == ["y", "u", "ref_y"]
    assert log.summary()["torn"] is True and log.summary()["n_samples"] == 0


def test_damaged_footer_is_salvaged_as_torn(streamed, tmp_path):
    _, data, _, _ = streamed
    bad = bytearray(data)
    bad[-30:-8] = bytes(22)  # footer zeroed, closing magic intact
    path = tmp_path / "bad-footer.mcap"
    path.write_bytes(bytes(bad))
    log = read_run(path)
    written = {k: v for k, v in COMPLETED.items() if v is not None}  # None values are left out of the record
    assert log.torn and log.n_samples == 8 * BLOCK and log.outcome == {**written, "n_samples": 8 * BLOCK}


WRITER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from labrunner.logs import RunLogWriter
    from test_logs_salvage import BLOCK, ramp

    with RunLogWriter(sys.argv[1], metadata={"run": {"point_id": "killed"}}, fs=1000.0,
                      channels=["y", "u", "ref_y"], flush_interval_s=0.0) as w:
        k = 0
        while True:
            w.write_block(k, ramp(k, BLOCK))
            k += BLOCK
            print(k, flush=True)
            time.sleep(0.005)
    """
)


def test_sigkilled_writer_leaves_a_salvageable_file(tmp_path):
    path = tmp_path / "killed.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.path.dirname(__file__), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        written = [int(proc.stdout.readline()) for _ in range(6)]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    log = read_run(path)
    assert log.torn and log.outcome is None
    assert log.metadata["run"]["point_id"] == "killed"
    # every block reported flushed before the kill survives, whole
    assert log.n_samples >= written[-1] and log.n_samples % BLOCK == 0
    expected = ramp(0, log.n_samples)
    for name, values in expected.items():
        assert np.array_equal(log.frame[name].to_numpy(), values), name
