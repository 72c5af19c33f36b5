"""Reading run logs: the signals as a DataFrame, the metadata, the outcome; salvage of torn files.

A finished file is read through its summary (``mcap``'s seeking reader). The signals come from
``/run/samples`` (formats ``labrunner-4`` and ``labrunner-3``, the same but for message indexes:
each sample once, its ``sequence`` the sample index; a chunk of the writer's fixed-size messages is
read as one numpy view, the indexes unused), or from ``/run/blocks``
where the file has them (thinned samples, and the logs of format ``labrunner-2``, which held both
topics): only the chunks of the topic read are decompressed. A *torn* file (no footer or summary: its writer was
killed) is read front to back with ``mcap``'s stream reader, in file order, keeping every record
up to the first incomplete one — all complete chunks survive.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import FOOTER_SIZE, SeekingReader
from mcap.records import Attachment, Channel, Chunk, ChunkIndex, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, StreamReader, get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC

from labrunner.errors import InvalidParameter
from labrunner.logs import schema
from labrunner.logs.mcap_writer import message_row
from labrunner.logs.metadata_text import decode_record
from labrunner.logs.writer import PLAIN_FORMATS

if TYPE_CHECKING:  # pandas only where a frame is built: a worker writing logs imports labrunner.logs without it
    import pandas as pd

# What a file cut short raises while being read: end of data, a truncated chunk, a bad record.
_TRUNCATED = (McapError, struct.error, zstandard.ZstdError, ValueError, EOFError)
_RECORD = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, start and end time, size, CRC, compression length
_CHANNEL_SEQUENCE = struct.Struct("<HI")
_MESSAGE_HEADER = 22  # channel id, sequence, log time, publish time
#: The records buffer's first size (it grows, doubling, as decompressed bytes arrive).
_FIRST_RECORDS = 1 << 20


@dataclass(frozen=True, eq=False)
class RunLog:
    """One run read back: ``data`` holds one float64 row per signal (``names``), sample k at
    t = k / fs; :attr:`frame` is the same as a pandas table (index ``t`` [s], one column per
    signal), built when first asked for, so that plotting a run needs no pandas."""

    data: np.ndarray  # (signals, samples)
    names: tuple[str, ...]  # the signals, in the order of the rows of ``data``
    metadata: dict[str, dict[str, Any]]  # every metadata record but ``outcome``, JSON-decoded
    outcome: dict[str, Any] | None  # None: the run never finished (torn file)
    torn: bool  # no footer/summary: salvaged by the stream reader
    fs: float  # sampling rate [Hz]
    channels: dict[str, dict[str, Any]] = field(default_factory=dict)  # signal → role, unit
    attachments: dict[str, bytes] = field(default_factory=dict)
    damaged: str = ""  # non-empty: the summary is intact but some chunks could not be read (what and where)

    @property
    def n_samples(self) -> int:
        return self.data.shape[1]

    @property
    def signals(self) -> list[str]:
        return list(self.names)

    @property
    def t(self) -> np.ndarray:
        """Sample times k / fs [s] (the index of :attr:`frame`)."""
        return np.arange(self.n_samples) / self.fs

    def signal(self, name: str) -> np.ndarray:
        """One signal's samples (a row of ``data``); KeyError for a signal the run does not log."""
        try:
            return self.data[self.names.index(name)]
        except ValueError:
            raise KeyError(name) from None

    @functools.cached_property
    def frame(self) -> pd.DataFrame:
        import pandas as pd

        index = pd.Index(self.t, name="t")
        return pd.DataFrame(self.data.T, index=index, columns=list(self.names), copy=False)

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
                "damaged": self.damaged,
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


def _decode_json_record(record: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, text in record.items():
        try:
            out[key] = json.loads(text)
        except ValueError:  # written by another tool: keep the text
            out[key] = text
    return out


def _decode_records(raw: dict[str, dict[str, str]]) -> dict[str, dict[str, Any]]:
    """Metadata records of one file to Python values: plain text (this format, marked by
    ``run.log_format``), or every value JSON text (logs of labrunner before it, which always
    wrote a ``run`` record without that mark)."""
    plain = "run" not in raw or raw["run"].get("log_format") in PLAIN_FORMATS
    decode = decode_record if plain else _decode_json_record
    return {name: decode(record) for name, record in raw.items()}


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


def _messages(data: bytes | memoryview, channel_ids: set[int]) -> Iterator[tuple[int, memoryview]]:
    """``(sequence, payload)`` of the messages of ``channel_ids`` in decompressed chunk records
    (others skipped)."""
    view, pos, end = memoryview(data), 0, len(data)
    while pos + _RECORD.size <= end:
        opcode, length = _RECORD.unpack_from(data, pos)
        body = pos + _RECORD.size
        if opcode == Opcode.MESSAGE:
            channel, sequence = _CHANNEL_SEQUENCE.unpack_from(data, body)
            if channel in channel_ids:
                yield sequence, view[body + _MESSAGE_HEADER : body + length]
        pos = body + length


def _sample_rows(records: memoryview, channel_ids: set[int], layout: schema.Layout) -> tuple[np.ndarray, np.ndarray]:
    """``(k, values)`` of the ``/run/samples`` messages in one chunk's records: sample indexes and
    (signals, n) float64 (``layout``: the schema's float32 fields). A chunk of the writer's
    equal-sized messages of one channel is read as one numpy view; any other valid chunk message
    by message."""
    n_signals = len(layout)
    (channel,) = channel_ids if len(channel_ids) == 1 else (0,)
    row = message_row(channel, schema.sample_dtype(layout), schema.sample_tags(layout))
    size = row.dtype.itemsize
    if channel and len(records) % size == 0 and len(records):
        rows = np.frombuffer(records, dtype=row.dtype)
        head = np.frombuffer(records, np.uint8).reshape(-1, size)
        template = row.view(np.uint8)
        data = rows["data"]
        tags_ok = all((data[f"k_s{j}"] == row["data"][f"k_s{j}"][0]).all() for j in range(n_signals))
        if tags_ok and (head[:, :11] == template[:11]).all():
            return rows["sequence"].astype(np.int64), np.stack([data[f"s{j}"] for j in range(n_signals)])
    sequences, payloads = [], []
    for sequence, payload in _messages(records, channel_ids):
        sequences.append(sequence)
        payloads.append(payload)
    return np.array(sequences, dtype=np.int64), schema.decode_samples(payloads, layout)


class _Frame:
    """The signals, gathered block by block into one (signals × samples) float64 array that
    grows as needed; samples that no complete block covered stay NaN."""

    def __init__(self, names: list[str], n_samples: int = 0) -> None:
        self.rows = {name: j for j, name in enumerate(names)}
        self.data = np.full((len(names), n_samples), np.nan)
        self.n = 0  # samples covered so far, up to the last one of any block
        self.fs = math.nan  # from the first block that states it

    def add(self, block: tuple[int, float, dict[str, np.ndarray]]) -> None:
        """Copy one decoded block in (its values may be views of a buffer about to be reused)."""
        first, fs, signals = block
        if math.isnan(self.fs) and math.isfinite(fs):
            self.fs = fs
        for name in signals.keys() - self.rows.keys():
            self.rows[name] = len(self.rows)
        stop = max((first + len(v) for v in signals.values()), default=0)
        rows, cols = self.data.shape
        if len(self.rows) > rows or stop > cols:
            grown = np.full((len(self.rows), max(stop, 2 * cols)), np.nan)
            grown[:rows, :cols] = self.data
            self.data = grown
        for name, values in signals.items():
            self.data[self.rows[name], first : first + len(values)] = values
        self.n = max(self.n, stop)

    def put(self, k: np.ndarray, values: np.ndarray) -> None:
        """Copy samples at indexes ``k`` in (``values``: one row per signal, in the names' order)."""
        if not len(k):
            return
        stop = int(k.max()) + 1
        rows, cols = self.data.shape
        if stop > cols:
            grown = np.full((rows, max(stop, 2 * cols)), np.nan)
            grown[:, :cols] = self.data
            self.data = grown
        self.data[: values.shape[0], k] = values
        self.n = max(self.n, stop)

    def samples(self) -> np.ndarray:
        """(signals, samples covered), one row per signal in order of first appearance."""
        return self.data[:, : self.n] if self.n == self.data.shape[1] else np.ascontiguousarray(self.data[:, : self.n])


class _ChunkReader:
    """Decompresses the chunks of one file into two reused buffers (compressed and records):
    fresh memory costs a page fault per 4 KiB, a third of the decompression time of a 32 kHz run.

    The sizes the chunk index states are the file's word, not believed before the data bear them
    out: the compressed buffer is at most the file's size, and the records buffer grows only as
    decompressed bytes arrive (a 41 kB file whose index claims 1.5 GB allocates what its chunks
    really hold, then fails its size check)."""

    def __init__(self, f: BinaryIO, indexes: list[ChunkIndex], file_size: int) -> None:
        self.f = f
        self.raw = bytearray(min(max((c.chunk_length for c in indexes), default=0), file_size))
        self.out = bytearray(min(max((c.uncompressed_size for c in indexes), default=0), _FIRST_RECORDS))
        self.zstd = zstandard.ZstdDecompressor()

    def records(self, index: ChunkIndex) -> memoryview:
        """The uncompressed records of the chunk at ``index`` (valid until the next call);
        zstd here, other compressions through ``mcap``."""
        raw = memoryview(self.raw)[: index.chunk_length]
        self.f.seek(index.chunk_start_offset)
        if self.f.readinto(raw) != index.chunk_length:
            raise McapError(f"chunk at offset {index.chunk_start_offset} is cut short")
        opcode, _, _, _, size, crc, name_length = _CHUNK_HEAD.unpack_from(raw)
        if opcode != Opcode.CHUNK:
            raise McapError(f"no chunk at offset {index.chunk_start_offset}")
        start = _CHUNK_HEAD.size + name_length + 8
        compression = bytes(raw[_CHUNK_HEAD.size : start - 8])
        if compression != b"zstd":
            stream, length = get_chunk_data_stream(Chunk.read(ReadDataStream(io.BytesIO(raw[_RECORD.size :]))))
            return memoryview(stream.read(length))
        (length,) = struct.unpack_from("<Q", raw, start - 8)
        with self.zstd.stream_reader(raw[start : start + length], read_across_frames=True) as source:
            done = 0
            while done < size:
                if done == len(self.out):  # a new buffer, not a resize: the last chunk's view may live on
                    grown = bytearray(min(size, 2 * len(self.out) or _FIRST_RECORDS))
                    grown[:done] = self.out
                    self.out = grown
                with memoryview(self.out) as view:
                    got = source.readinto(view[done : min(size, len(self.out))])
                if not got:
                    break
                done += got
        if done != size:
            raise McapError(f"chunk at offset {index.chunk_start_offset} holds {done} bytes, not {size}")
        out = memoryview(self.out)[:size]
        if crc and zlib.crc32(out) != crc:  # zstd without a frame checksum decodes damage silently
            raise McapError(f"chunk at offset {index.chunk_start_offset} fails its CRC")
        return out


def _read_finished(f: BinaryIO, reader: SeekingReader) -> tuple[dict, dict, _Frame, str]:
    summary = reader.get_summary()
    assert summary is not None
    records = _decode_records({m.name: m.metadata for m in reader.iter_metadata()})
    attachments = {a.name: a.data for a in reader.iter_attachments()}
    names = list(records.get("channels", {}))
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    blocks = {cid for cid, ch in summary.channels.items() if ch.topic == schema.BLOCK_TOPIC}
    if not blocks or not any(counts.get(cid, 1) for cid in blocks):  # no blocks: the samples hold the signals
        blocks = set()
    ids = blocks or {cid for cid, ch in summary.channels.items() if ch.topic == schema.SAMPLES_TOPIC}
    chunks = sorted(
        (c for c in summary.chunk_indexes if not c.message_index_offsets or ids & c.message_index_offsets.keys()),
        key=lambda c: c.chunk_start_offset,
    )
    # the outcome's sample count sizes the frame (which grows if it is wrong), bounded by what the
    # chunks can hold so that a damaged record cannot ask for more memory than the file implies
    hint = records.get("outcome", {}).get("n_samples", 0)
    file_size = f.seek(0, io.SEEK_END)
    bound = min(sum(c.uncompressed_size for c in chunks) // 8, file_size) // max(1, len(names))
    frame = _Frame(names, min(hint, bound) if isinstance(hint, int) and hint > 0 else 0)
    layout: schema.Layout = ()
    if not blocks:
        frame.fs = float(records.get("run", {}).get("fs", math.nan))
        layout = _layout([summary.schemas.get(summary.channels[cid].schema_id) for cid in ids], len(names))
    chunk_reader = _ChunkReader(f, chunks, file_size)
    bad = []
    for index in chunks:  # a damaged chunk is skipped: its samples stay NaN, the others are read
        try:
            chunk = chunk_reader.records(index)
            if blocks:
                for _, payload in _messages(chunk, ids):
                    frame.add(schema.decode_block(payload))
            else:
                frame.put(*_sample_rows(chunk, ids, layout))
        except _TRUNCATED as exc:
            bad.append(f"offset {index.chunk_start_offset}: {exc}")
    damaged = f"{len(bad)} of {len(chunks)} data chunks unreadable ({bad[0]})" if bad else ""
    return records, attachments, frame, damaged


def _read_torn(f: BinaryIO) -> tuple[dict, dict, _Frame]:
    raw: dict[str, dict[str, str]] = {}
    attachments: dict[str, bytes] = {}
    topics: dict[int, str] = {}
    schemas: dict[int, Schema] = {}
    sample_schema: Schema | None = None
    blocks: list[bytes] = []
    samples: list[tuple[int, bytes]] = []
    try:
        for record in StreamReader(f).records:
            if isinstance(record, Metadata):
                raw[record.name] = record.metadata
            elif isinstance(record, Attachment):
                attachments[record.name] = record.data
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                topics[record.id] = record.topic
                if record.topic == schema.SAMPLES_TOPIC:
                    sample_schema = schemas.get(record.schema_id)
            elif isinstance(record, Message) and topics.get(record.channel_id) == schema.BLOCK_TOPIC:
                blocks.append(record.data)
            elif isinstance(record, Message) and topics.get(record.channel_id) == schema.SAMPLES_TOPIC:
                samples.append((record.sequence, record.data))
    except _TRUNCATED:
        pass  # the rest of the file is incomplete
    frame = _Frame(_channel_names(raw))
    if blocks:
        for payload in blocks:
            frame.add(schema.decode_block(payload))
    elif samples:
        frame.fs = float(decode_record(raw.get("run", {})).get("fs", math.nan))
        k = np.array([seq for seq, _ in samples], dtype=np.int64)
        layout = _layout([sample_schema], len(frame.rows))
        frame.put(k, schema.decode_samples([payload for _, payload in samples], layout))
    return _decode_records(raw), attachments, frame


def _layout(schemas: list[Schema | None], n_signals: int) -> schema.Layout:
    """Which of the ``/run/samples`` fields are float32, from the channel's stored schema (one
    schema expected; none, or several that differ: all float64, as labrunner-3 logs had)."""
    found = {schema.float32_fields(s.data, n_signals) for s in schemas if s is not None}
    return found.pop() if len(found) == 1 else (False,) * n_signals


def _channel_names(raw: dict[str, dict[str, str]]) -> list[str]:
    """Signal names from a raw ``channels`` record (either format)."""
    return list(decode_record(raw.get("channels", {})))


def read_run(path: str | os.PathLike[str]) -> RunLog:
    """Read a run log (finished or torn) into a :class:`RunLog`."""
    with _open(path) as f:
        reader = _finished(f)
        torn = reader is None
        damaged = ""
        try:
            records, attachments, frame, damaged = (*_read_torn(f), "") if torn else _read_finished(f, reader)
        except _TRUNCATED:  # footer present but the summary's records are damaged: salvage what is readable
            torn = True
            f.seek(0)
            records, attachments, frame = _read_torn(f)
    _check_records(records, path)
    outcome = records.pop("outcome", None)
    stated = records.get("run", {}).get("fs", math.nan)
    fs = frame.fs if math.isfinite(frame.fs) else float(stated)
    names = tuple(frame.rows)
    counted = (outcome or {}).get("n_samples")
    if not torn and not damaged and isinstance(counted, int) and frame.n < counted:
        damaged = f"its data chunks hold {frame.n} of the {counted} samples its outcome counts"
    return RunLog(frame.samples(), names, records, outcome, torn, fs, records["channels"], attachments, damaged)


def _check_records(records: dict[str, dict[str, Any]], path: str | os.PathLike[str]) -> None:
    """Refuse a file whose records are not what labrunner writes (another tool's MCAP)."""

    def foreign(why: str) -> InvalidParameter:
        return InvalidParameter("path", f"not a labrunner run log ({why}): {str(path)!r}")

    if "channels" not in records:
        raise foreign("no 'channels' metadata")
    for name, info in records["channels"].items():
        if not isinstance(info, dict) or not all(isinstance(info.get(k, ""), str) for k in ("role", "unit")):
            raise foreign(f"channel {name!r} is not described by a role and a unit")
    fs = records.get("run", {}).get("fs", math.nan)
    if isinstance(fs, bool) or not isinstance(fs, (int, float)):
        raise foreign(f"run.fs is {fs!r}, not a number")


def read_metadata(path: str | os.PathLike[str]) -> dict[str, dict[str, Any]]:
    """Every metadata record (``run``, ``config``, ``channels``, ``outcome`` if finished), decoded,
    without reading the signals: through the metadata index, or a scan of a torn file."""
    with _open(path) as f:
        reader = _finished(f)
        if reader is not None:
            return _decode_records({m.name: m.metadata for m in reader.iter_metadata()})
        raw = {}
        try:
            for record in StreamReader(f, emit_chunks=True).records:  # chunks are not decompressed
                if isinstance(record, Metadata):
                    raw[record.name] = record.metadata
        except _TRUNCATED:
            pass
        return _decode_records(raw)


def read_outcome(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """The run's outcome record (with ``n_samples``), or None when the run never finished."""
    return read_metadata(path).get("outcome")
