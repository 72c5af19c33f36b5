"""A chunked, zstd-compressed MCAP writer that takes messages in bulk.

Why not ``mcap.writer.Writer``: it builds each message record through about fifteen Python calls
(≈ 6 µs a message), 6 ms for a 1000-sample motor run with its per-sample preview — twice what
the engine needs to simulate the run. Here a batch of equal-sized messages becomes one numpy
structured array (MCAP message header + payload per row) and its message index one more, so the
cost per message is a few bytes copied.

The file has the layout ``mcap``'s writer produces (MCAP spec v0): header; data section with
metadata, attachments and chunks, each chunk followed by the message index of every indexed
channel in it, chunks with the CRC of their uncompressed records; data end; summary with the
schemas and channels repeated, statistics, chunk, attachment and metadata indexes, summary
offsets; footer with the summary CRC. Three differences: schemas and channels go in the data
section when they are added rather than inside the next chunk, so a file torn before its first
chunk still declares its topics; each channel's messages go into chunks of their own, so that
reading one topic decompresses nothing of another; and a channel may be written without message
indexes (``indexed=False``; optional in MCAP, and 16 uncompressed bytes a message less, but
@mcap/core's indexed reader — Foxglove's — refuses such chunks: only the old labrunner-3 layout,
written for tests, uses it). :meth:`BulkWriter.copy_chunk` copies a chunk of another file as it
is and indexes it (how :mod:`labrunner.logs.upgrade` rewrites those logs). The records a file
writes once (header, schemas, channels, attachments) are written by ``mcap.records``' own
classes, those every file writes (metadata, indexes, statistics, footer) by
:mod:`labrunner.logs.mcap_records` in one ``struct`` call each. The start of a file that many files
share (header, schemas, channels, attachments, constant metadata) can be captured once as a
:class:`Prefix` and written again as bytes (:meth:`BulkWriter.resume`).
"""

from __future__ import annotations

import functools
import struct
import threading
import zlib
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import BinaryIO

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Attachment, AttachmentIndex, Channel, Chunk, Header, McapRecord, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC

from labrunner.logs import mcap_records
from labrunner.logs.mcap_index import INDEX_ENTRY, MESSAGE_HEADER, message_indexes

CHUNK_SIZE = 1 << 20  # uncompressed bytes of records per chunk (mcap's default)
# zstd level 1: level 3 (zstd's and mcap's default) makes a 3 s, 32 kHz plate run's file < 1 %
# and a motor run's 3 % smaller at 1.7× the compression time; negative levels give up entropy
# coding of the float64 mantissas (files ~10 % larger) for 5× faster compression.
ZSTD_LEVEL = 1
_CHUNK_TAIL = struct.pack("<I", 4) + b"zstd"  # the chunks' compression, as MCAP names it

_MESSAGE_INDEX_HEADER = struct.Struct("<BQHI")  # opcode, record length, channel, index byte length
_CHUNK_HEADER = struct.Struct("<BQQQQI")  # opcode, record length, start and end time, size, CRC
_FOOTER_PREFIX = struct.Struct("<BQQQ")  # opcode, record length, summary start, summary offset start


@functools.lru_cache(maxsize=16)
def _compressor(level: int, thread: int | None = None) -> zstandard.ZstdCompressor:
    """One compressor per level and thread (its context is reused: creating one costs ~50 µs; a
    compressor must not be used by two threads at once)."""
    return zstandard.ZstdCompressor(level=level)


def message_row(channel_id: int, payload: np.dtype | int, template: np.ndarray | None = None) -> np.ndarray:
    """One MCAP message record of ``channel_id`` as a structured row whose ``data`` field has dtype
    ``payload`` (a structured dtype the caller fills field by field, or a byte count for raw bytes).

    Row layout: opcode 0x05, record length (u64), channel id (u16), sequence (u32), log time and
    publish time (u64, ns), payload. Opcode, length and channel are filled here, and the payload
    from ``template`` (one payload, e.g. the constant tags of a protobuf message) if given.
    """
    payload = np.dtype(("u1", (payload,))) if isinstance(payload, int) else np.dtype(payload)
    dtype = np.dtype(
        {
            "names": ["opcode", "length", "channel", "sequence", "log_time", "publish_time", "data"],
            "formats": ["u1", "<u8", "<u2", "<u4", "<u8", "<u8", payload],
            "offsets": [0, 1, 9, 11, 15, 23, MESSAGE_HEADER.size],
            "itemsize": MESSAGE_HEADER.size + payload.itemsize,
        }
    )
    row = np.zeros(1, dtype=dtype)
    row["opcode"], row["length"], row["channel"] = Opcode.MESSAGE, dtype.itemsize - 9, channel_id
    if template is not None:
        row["data"] = template
    return row


def repeat_row(row: np.ndarray, n: int) -> np.ndarray:
    """``n`` copies of a :func:`message_row`, by broadcasting its bytes (10× faster than
    assigning fields); the caller fills ``sequence``, ``log_time`` and the payload's varying fields
    (:meth:`BulkWriter.add_records` sets the publish time)."""
    records = np.empty(n, dtype=row.dtype)
    records.view(np.uint8).reshape(n, row.dtype.itemsize)[...] = row.view(np.uint8)
    return records


def message_array(n: int, channel_id: int, payload: np.dtype | int, template: np.ndarray | None = None) -> np.ndarray:
    """``n`` MCAP message records of ``channel_id`` (:func:`message_row`, :func:`repeat_row`)."""
    return repeat_row(message_row(channel_id, payload, template), n)


def message_records(channel_id: int, log_times: np.ndarray, sequences: np.ndarray, payloads: np.ndarray) -> np.ndarray:
    """A :func:`message_array` holding ``payloads`` (n, size) uint8 of equal size, with their log
    times [ns] and sequence numbers."""
    records = message_array(payloads.shape[0], channel_id, payloads.shape[1])
    records["data"], records["log_time"], records["sequence"] = payloads, log_times, sequences
    return records


def _encoded(records: Sequence[McapRecord]) -> bytes:
    """Records as bytes, through ``mcap``'s own encoder."""
    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    return builder.end()


@dataclass(frozen=True)
class Prefix:
    """The start of a file as :meth:`BulkWriter.prefix` captured it: its bytes and the records
    the summary repeats or indexes, so that many files can begin with it without re-encoding."""

    data: bytes
    schemas: tuple[Schema, ...]
    channels: tuple[Channel, ...]
    attachment_indexes: tuple[bytes, ...]  # encoded records
    metadata_indexes: tuple[bytes, ...]  # encoded records
    unindexed: frozenset[int]  # channels whose chunks get no message index records
    summary_records: tuple[bytes, bytes]  # the schemas and the channels as the summary repeats them


class _Chunk:
    """An open chunk: its records as pieces (joined only by the compressor), per-channel indexes."""

    def __init__(self, indexed: bool) -> None:
        self.indexed = indexed
        self.pieces: list[bytes | np.ndarray] = []
        self.size = 0
        self.index: dict[int, list[np.ndarray]] = {}
        self.times: tuple[int, int] | None = None


class BulkWriter:
    """Write one MCAP file to ``stream`` (opened for binary writing; not closed here).

    Call :meth:`start` (or :meth:`resume` from a :class:`Prefix`), then in any order
    :meth:`add_schema`, :meth:`add_channel`, :meth:`add_metadata`, :meth:`add_attachment`,
    :meth:`add_message`, :meth:`add_messages`, :meth:`add_records` and :meth:`flush`, then
    :meth:`finish`. Each channel's messages collect in a chunk of their own (so that a reader of one
    topic decompresses only its chunks); chunks are closed when their records pass ``chunk_size``
    bytes, before a metadata record or an attachment, and at every flush.
    """

    def __init__(self, stream: BinaryIO, *, chunk_size: int = CHUNK_SIZE, level: int = ZSTD_LEVEL) -> None:
        self._stream = stream
        self._chunk_size = chunk_size
        self._level = level
        self._unindexed: set[int] = set()  # channels whose chunks get no message index records
        self._offset = 0  # bytes written to the stream
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[bytes] = []  # the summary's index records, encoded
        self._attachment_indexes: list[bytes] = []
        self._metadata_indexes: list[bytes] = []
        self._counts: dict[int, int] = defaultdict(int)  # messages per channel
        self._first_time: int | None = None
        self._last_time = 0
        self._open: dict[int, _Chunk] = {}  # channel id → its open chunk
        self._summary_records: tuple[bytes, bytes] | None = None  # a prefix's schemas and channels, encoded

    def _write(self, data: bytes | memoryview) -> None:
        self._stream.write(data)
        self._offset += len(data)

    def _write_record(self, record: McapRecord) -> int:
        """Write one small record with ``mcap``'s own encoder; return its length in bytes."""
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self._write(data)
        return len(data)

    def start(self, library: str, profile: str = "") -> None:
        """Magic and header record (``library`` names the writer)."""
        self._write(MCAP0_MAGIC)
        self._write_record(Header(profile=profile, library=library))

    def prefix(self) -> Prefix:
        """What was written so far (``stream`` must be a :class:`io.BytesIO`), to :meth:`resume` from."""
        self._close_chunks()
        return Prefix(
            self._stream.getvalue(),
            tuple(self._schemas),
            tuple(self._channels),  # type: ignore[attr-defined]
            tuple(self._attachment_indexes),
            tuple(self._metadata_indexes),
            frozenset(self._unindexed),
            (_encoded(self._schemas), _encoded(self._channels)),
        )

    def resume(self, prefix: Prefix) -> None:
        """Begin the file with ``prefix`` (instead of :meth:`start`): its bytes as they are."""
        self._write(prefix.data)
        self._schemas, self._channels = list(prefix.schemas), list(prefix.channels)
        self._attachment_indexes = list(prefix.attachment_indexes)
        self._metadata_indexes = list(prefix.metadata_indexes)
        self._unindexed = set(prefix.unindexed)
        self._summary_records = prefix.summary_records

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        """Register a schema (ids from 1); return its id."""
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._summary_records = None
        self._write_record(schema)
        return schema.id

    def add_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
        *,
        indexed: bool = True,
    ) -> int:
        """Register a channel (ids from 1); return its id. ``indexed=False``: its chunks get no
        message index records (optional in MCAP: the chunk index then lists no channel, and readers
        scan the chunk), which for one small message per sample would be 16 bytes a message,
        uncompressed — a third of a compact motor log."""
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata or {}),
        )
        self._channels.append(channel)
        self._summary_records = None
        self._write_record(channel)
        if not indexed:
            self._unindexed.add(channel.id)
        return channel.id

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record, after everything added so far (open chunks are closed first)."""
        self._close_chunks()
        offset = self._offset
        record = mcap_records.metadata(name, data)
        self._write(record)
        self._metadata_indexes.append(mcap_records.metadata_index(offset, len(record), name))

    def add_attachment(
        self, name: str, media_type: str, data: bytes, *, log_time: int = 0, create_time: int = 0
    ) -> None:
        """An attachment record (times in ns), after everything added so far."""
        self._close_chunks()
        offset = self._offset
        record = Attachment(create_time=create_time, log_time=log_time, name=name, media_type=media_type, data=data)
        length = self._write_record(record)
        index = AttachmentIndex(
            offset=offset,
            length=length,
            create_time=create_time,
            log_time=log_time,
            data_size=len(data),
            name=name,
            media_type=media_type,
        )
        self._attachment_indexes.append(_encoded([index]))

    def add_message(self, channel_id: int, log_time: int, sequence: int, parts: Sequence[bytes | np.ndarray]) -> None:
        """Append one message whose payload is ``parts`` concatenated (bytes-like pieces, joined
        only when the chunk is written); ``log_time`` [ns]."""
        length = MESSAGE_HEADER.size - 9 + sum(memoryview(p).nbytes for p in parts)
        header = MESSAGE_HEADER.pack(Opcode.MESSAGE, length, channel_id, sequence, log_time, log_time)
        chunk = self._chunk(channel_id)
        self._append(
            chunk,
            channel_id,
            np.array([log_time], dtype=np.uint64),
            np.array([chunk.size], dtype=np.uint64),
            [header, *parts],
        )

    def add_messages(self, channel_id: int, log_times: np.ndarray, sequences: np.ndarray, payloads: np.ndarray) -> None:
        """Append messages of one channel with equal-sized payloads, a (n, size) uint8 array
        (vectorised: one structured array of records); ``log_times`` [ns]."""
        self.add_records(channel_id, message_records(channel_id, log_times, sequences, payloads))

    def add_records(self, channel_id: int, records: np.ndarray) -> None:
        """Append messages of channel ``channel_id`` from a :func:`message_array` of it whose
        payloads, ``log_time`` and ``sequence`` are filled (publish time = log time, set here)."""
        records["publish_time"] = records["log_time"]
        size = records.dtype.itemsize
        start = 0
        while start < len(records):  # split where the open chunk fills up
            chunk = self._chunk(channel_id)
            stop = min(len(records), start + max(1, -(-(self._chunk_size - chunk.size) // size)))
            offsets = chunk.size + size * np.arange(stop - start, dtype=np.uint64)
            self._append(
                chunk, channel_id, records["log_time"][start:stop], offsets, [records[start:stop].view(np.uint8)]
            )
            start = stop

    def _chunk(self, channel_id: int) -> _Chunk:
        chunk = self._open.get(channel_id)
        if chunk is None:
            chunk = self._open[channel_id] = _Chunk(channel_id not in self._unindexed)
        return chunk

    def _append(self, chunk: _Chunk, channel_id: int, log_times: np.ndarray, offsets: np.ndarray, pieces: list) -> None:
        """Add records (``pieces``, in order) of one channel's messages at ``offsets`` in its open
        chunk; close the chunk once full."""
        entries = np.empty(len(offsets), dtype=INDEX_ENTRY)
        entries["log_time"], entries["offset"] = log_times, offsets
        chunk.index.setdefault(channel_id, []).append(entries)
        chunk.pieces += pieces
        chunk.size += sum(memoryview(p).nbytes for p in pieces)
        lo, hi = int(log_times.min()), int(log_times.max())
        chunk.times = (lo, hi) if chunk.times is None else (min(lo, chunk.times[0]), max(hi, chunk.times[1]))
        self._counts[channel_id] += len(entries)
        if chunk.size >= self._chunk_size:
            self._close_chunk(self._open.pop(channel_id))

    def _close_chunks(self) -> None:
        """Write every open chunk, in the order their channels opened them."""
        chunks, self._open = list(self._open.values()), {}
        for chunk in chunks:
            self._close_chunk(chunk)

    def _close_chunk(self, chunk: _Chunk) -> None:
        """Write one chunk (zstd) and its message indexes; no-op when it holds no message."""
        if chunk.times is None:
            return
        # joined and compressed in one call: ~30 µs a chunk less than zstd's streaming chunker (whose
        # buffers are fresh memory each time); the frame still records the content size
        records = b"".join(chunk.pieces)
        compressed = _compressor(self._level, threading.get_ident()).compress(records)
        index = {}
        for channel_id, parts in chunk.index.items() if chunk.indexed else ():
            index[channel_id] = np.concatenate(parts) if len(parts) > 1 else parts[0]
        self._write_chunk(chunk.times, chunk.size, zlib.crc32(records), _CHUNK_TAIL, compressed, index)

    def copy_chunk(self, chunk: Chunk) -> None:
        """Write ``chunk`` (read from another file) as it is, compressed data and CRC included,
        with a message index of every channel in it and its times taken from its messages, after
        everything added so far (open chunks are closed first). McapError for a chunk that holds
        anything but messages (e.g. schemas, as ``mcap``'s writer puts there: the summary would
        lack them)."""
        self._close_chunks()
        stream, size = get_chunk_data_stream(chunk, validate_crc=True)
        index = message_indexes(stream.read(size))
        if not index:
            return
        for channel_id, entries in index.items():
            self._counts[channel_id] += len(entries)
        times = [(int(e["log_time"].min()), int(e["log_time"].max())) for e in index.values()]
        span = (min(t[0] for t in times), max(t[1] for t in times))
        self._write_chunk(span, size, chunk.uncompressed_crc, mcap_records.string(chunk.compression), chunk.data, index)

    def _write_chunk(
        self,
        times: tuple[int, int],
        size: int,
        crc: int,
        compression: bytes,
        compressed: bytes,
        index: Mapping[int, np.ndarray],
    ) -> None:
        """Write a chunk record (``compression``: the encoded name), the message index of each
        channel in ``index`` after it (channel id → :data:`INDEX_ENTRY` rows), its chunk index."""
        start_time, end_time = times
        compressed_size = len(compressed)
        length = _CHUNK_HEADER.size - 9 + len(compression) + 8 + compressed_size
        chunk_start = self._offset
        self._write(
            _CHUNK_HEADER.pack(Opcode.CHUNK, length, start_time, end_time, size, crc)
            + compression
            + struct.pack("<Q", compressed_size)
        )
        self._write(compressed)
        chunk_length = self._offset - chunk_start
        offsets = {}
        for channel_id, entries in index.items():
            offsets[channel_id] = self._offset
            self._write(
                _MESSAGE_INDEX_HEADER.pack(Opcode.MESSAGE_INDEX, 6 + entries.nbytes, channel_id, entries.nbytes)
            )
            self._write(memoryview(entries).cast("B"))
        self._chunk_indexes.append(
            mcap_records.chunk_index(
                start_time,
                end_time,
                chunk_start,
                chunk_length,
                offsets,
                self._offset - chunk_start - chunk_length,
                compression[4:].decode(),
                compressed_size,
                size,
            )
        )
        self._first_time = start_time if self._first_time is None else min(self._first_time, start_time)
        self._last_time = max(self._last_time, end_time)

    def flush(self) -> None:
        """Close the open chunks and flush the stream (no fsync): what was added survives a kill."""
        self._close_chunks()
        self._stream.flush()

    def finish(self) -> None:
        """Close the open chunks; write data end, summary, footer and closing magic; flush."""
        self._close_chunks()
        self._write(mcap_records.data_end())
        summary_start = self._offset
        statistics = mcap_records.statistics(
            sum(self._counts.values()),
            len(self._schemas),
            len(self._channels),
            len(self._attachment_indexes),
            len(self._metadata_indexes),
            len(self._chunk_indexes),
            self._first_time or 0,
            self._last_time,
            self._counts,
        )
        schemas, channels = self._summary_records or (_encoded(self._schemas), _encoded(self._channels))
        groups = [
            (Opcode.SCHEMA, schemas),
            (Opcode.CHANNEL, channels),
            (Opcode.STATISTICS, statistics),
            (Opcode.CHUNK_INDEX, b"".join(self._chunk_indexes)),
            (Opcode.ATTACHMENT_INDEX, b"".join(self._attachment_indexes)),
            (Opcode.METADATA_INDEX, b"".join(self._metadata_indexes)),
        ]
        pieces, offsets, at = [], [], summary_start
        for opcode, group in groups:
            if group:
                pieces.append(group)
                offsets.append(mcap_records.summary_offset(opcode, at, len(group)))
                at += len(group)
        summary = b"".join(pieces + offsets)
        summary_offset_start = at
        crc = zlib.crc32(
            _FOOTER_PREFIX.pack(Opcode.FOOTER, 20, summary_start, summary_offset_start), zlib.crc32(summary)
        )
        self._write(summary + mcap_records.footer(summary_start, summary_offset_start, crc) + MCAP0_MAGIC)
        self._stream.flush()
