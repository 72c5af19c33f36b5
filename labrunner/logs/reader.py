"""Reading run logs: the signals as a DataFrame, the metadata, the outcome; salvage of torn files.

A finished file is read through its summary (``mcap``'s seeking reader): only chunks that hold
``/run/blocks`` messages are decompressed, and their records are scanned for block messages
without decoding the per-sample preview. A *torn* file (no footer or summary: its writer was
killed) is read front to back with ``mcap``'s stream reader, in file order, keeping every record
up to the first incomplete one — all complete chunks survive.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import pandas as pd
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import FOOTER_SIZE, SeekingReader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata
from mcap.stream_reader import MAGIC_SIZE, StreamReader, get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC

from labrunner.errors import InvalidParameter
from labrunner.logs import schema

# What a file cut short raises while being read: end of data, a truncated chunk, a bad record.
_TRUNCATED = (McapError, struct.error, zstandard.ZstdError, ValueError, EOFError)
_RECORD = struct.Struct("<BQ")
_CHANNEL_ID = struct.Struct("<H")
_MESSAGE_HEADER = 22  # channel id, sequence, log time, publish time


@dataclass(frozen=True)
class RunLog:
    """One run read back: ``frame`` has index ``t`` [s] and one float64 column per signal."""

    frame: pd.DataFrame
    metadata: dict[str, dict[str, Any]]  # every metadata record but ``outcome``, JSON-decoded
    outcome: dict[str, Any] | None  # None: the run never finished (torn file)
    torn: bool  # no footer/summary: salvaged by the stream reader
    fs: float  # sampling rate [Hz]
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)  # signal → role, unit
    attachments: dict[str, bytes] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        return len(self.frame)

    @property
    def signals(self) -> list[str]:
        return [str(c) for c in self.frame.columns]

    def summary(self) -> dict[str, Any]:
        """What ``labrunner inspect --json`` prints (strict JSON: non-finite floats as strings)."""
        return _strict_json(
            {
                "outcome": self.outcome,
                "n_samples": self.n_samples,
                "fs": self.fs,
                "signals": self.signals,
                "metadata": self.metadata,
                "attachments": {name: len(data) for name, data in self.attachments.items()},
                "torn": self.torn,
            }
        )


def _strict_json(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: _strict_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_strict_json(v) for v in value]
    return value


def _decode_record(record: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, text in record.items():
        try:
            out[key] = json.loads(text)
        except ValueError:  # written by another tool: keep the text
            out[key] = text
    return out


def _open(path: str | os.PathLike[str]) -> BinaryIO:
    path = Path(path)
    if not path.is_file():
        raise InvalidParameter("path", f"no such run log: {str(path)!r}")
    f = open(path, "rb")  # noqa: SIM115 - returned to a with statement
    if f.read(MAGIC_SIZE) != MCAP0_MAGIC:
        f.close()
        raise InvalidParameter("path", f"not an MCAP file: {str(path)!r}")
    f.seek(0)
    return f


def _finished(f: BinaryIO) -> SeekingReader | None:
    """A seeking reader when the file ends with a footer and a summary, else None (torn).

    Leaves ``f`` at its start either way.
    """
    size = f.seek(0, io.SEEK_END)
    f.seek(max(0, size - FOOTER_SIZE - MAGIC_SIZE))
    tail = f.read(FOOTER_SIZE + MAGIC_SIZE)
    f.seek(0)
    if size < 2 * MAGIC_SIZE + FOOTER_SIZE or tail[0] != Opcode.FOOTER or tail[-MAGIC_SIZE:] != MCAP0_MAGIC:
        return None
    try:
        reader = SeekingReader(f)
        return reader if reader.get_summary() is not None else None
    except _TRUNCATED:
        return None
    finally:
        f.seek(0)


def _block_payloads(data: bytes, channel_ids: set[int]) -> Iterator[memoryview]:
    """Payloads of the messages of ``channel_ids`` in decompressed chunk records (others skipped)."""
    view, pos, end = memoryview(data), 0, len(data)
    while pos + _RECORD.size <= end:
        opcode, length = _RECORD.unpack_from(data, pos)
        body = pos + _RECORD.size
        if opcode == Opcode.MESSAGE and _CHANNEL_ID.unpack_from(data, body)[0] in channel_ids:
            yield view[body + _MESSAGE_HEADER : body + length]
        pos = body + length


def _read_finished(f: BinaryIO, reader: SeekingReader) -> tuple[dict, dict, list]:
    summary = reader.get_summary()
    assert summary is not None
    records = {m.name: _decode_record(m.metadata) for m in reader.iter_metadata()}
    attachments = {a.name: a.data for a in reader.iter_attachments()}
    ids = {cid for cid, ch in summary.channels.items() if ch.topic == schema.BLOCK_TOPIC}
    blocks = []
    for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        if index.message_index_offsets and not ids & index.message_index_offsets.keys():
            continue
        f.seek(index.chunk_start_offset + _RECORD.size)
        stream, length = get_chunk_data_stream(Chunk.read(ReadDataStream(f)))
        blocks += [schema.decode_block(p) for p in _block_payloads(stream.read(length), ids)]
    return records, attachments, blocks


def _read_torn(f: BinaryIO) -> tuple[dict, dict, list]:
    records: dict[str, dict[str, Any]] = {}
    attachments: dict[str, bytes] = {}
    ids: set[int] = set()
    blocks = []
    try:
        for record in StreamReader(f).records:
            if isinstance(record, Metadata):
                records[record.name] = _decode_record(record.metadata)
            elif isinstance(record, Attachment):
                attachments[record.name] = record.data
            elif isinstance(record, Channel) and record.topic == schema.BLOCK_TOPIC:
                ids.add(record.id)
            elif isinstance(record, Message) and record.channel_id in ids:
                blocks.append(schema.decode_block(record.data))
    except _TRUNCATED:
        pass  # the rest of the file is incomplete
    return records, attachments, blocks


def _frame(blocks: list, names: list[str], fs: float) -> pd.DataFrame:
    """One column per signal (the described ones first, then any other a block carries); samples
    that no complete block covered are NaN."""
    names = list(dict.fromkeys([*names, *(n for _, _, s in blocks for n in s)]))
    n = max((first + len(v) for first, _, s in blocks for v in s.values()), default=0)
    data = np.full((len(names), n), np.nan)
    rows = {name: j for j, name in enumerate(names)}
    for first, _, signals in blocks:
        for name, values in signals.items():
            data[rows[name], first : first + len(values)] = values
    index = pd.Index(np.arange(n) / fs, name="t")
    return pd.DataFrame(data.T, index=index, columns=names, copy=False)


def read_run(path: str | os.PathLike[str]) -> RunLog:
    """Read a run log (finished or torn) into a :class:`RunLog`."""
    with _open(path) as f:
        reader = _finished(f)
        torn = reader is None
        try:
            records, attachments, blocks = _read_torn(f) if torn else _read_finished(f, reader)
        except _TRUNCATED:  # footer present but the data is damaged: salvage what is readable
            torn = True
            f.seek(0)
            records, attachments, blocks = _read_torn(f)
    if "channels" not in records:
        raise InvalidParameter("path", f"not a labrunner run log (no 'channels' metadata): {str(path)!r}")
    outcome = records.pop("outcome", None)
    channels = records["channels"]
    block_fs = [b[1] for b in blocks if math.isfinite(b[1])]
    fs = block_fs[0] if block_fs else float(records.get("run", {}).get("fs", math.nan))
    frame = _frame(blocks, list(channels), fs)
    return RunLog(frame, records, outcome, torn, fs, channels, attachments)


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """Every metadata record (``run``, ``config``, ``channels``, ``outcome`` if finished), JSON-
    decoded, without reading the signals: through the metadata index, or a scan of a torn file."""
    with _open(path) as f:
        reader = _finished(f)
        if reader is not None:
            return {m.name: _decode_record(m.metadata) for m in reader.iter_metadata()}
        records = {}
        try:
            for record in StreamReader(f, emit_chunks=True).records:  # chunks are not decompressed
                if isinstance(record, Metadata):
                    records[record.name] = _decode_record(record.metadata)
        except _TRUNCATED:
            pass
        return records


def read_outcome(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The run's outcome record (with ``n_samples``), or None when the run never finished."""
    return read_metadata(path).get("outcome")

