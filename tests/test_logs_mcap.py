"""The bulk MCAP writer and the vectorised per-sample encoding against their references.

References: the ``mcap`` package's own writer (same messages, metadata and attachments must read
back identically with its reader, CRCs validated; its record classes, byte for byte, for the
records written per file) and the MCAP spec for what its reader does not
check (message indexes, summary CRC); for the per-sample messages, the classes ``google.protobuf``
generates from the schema (decoding, and its own serialisation byte for byte).
"""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import CompressionType, Writer
from test_logs_support import COMPLETED, motor_run

from labrunner.logs import mcap_records, read_run, schema as log_schema, write_run
from labrunner.logs.mcap_index import message_indexes
from labrunner.logs.mcap_writer import BulkWriter
from labrunner.logs.metadata_text import encode_record


def bits(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64).view(np.uint64)


def write_both(writer_calls) -> tuple[bytes, bytes]:
    """The same calls through ``mcap``'s Writer and through BulkWriter (small chunks)."""
    ref, ours = io.BytesIO(), io.BytesIO()
    w = Writer(ref, chunk_size=4096, compression=CompressionType.ZSTD)
    w.start(library="reference")
    b = BulkWriter(ours, chunk_size=4096)
    b.start(library="reference")
    writer_calls(w, b)
    w.finish()
    b.finish()
    return ref.getvalue(), ours.getvalue()


def content(data: bytes):
    """What ``mcap``'s reader sees, CRCs validated: messages in file order, metadata, attachments, statistics."""
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    summary = reader.get_summary()
    messages = sorted(  # file order differs: BulkWriter keeps each channel in chunks of its own
        (channel.topic, schema.name, m.sequence, m.log_time, m.publish_time, bytes(m.data))
        for schema, channel, m in reader.iter_messages(log_time_order=False)
    )
    in_time_order = [(c.topic, m.log_time, m.sequence) for _, c, m in reader.iter_messages(log_time_order=True)]
    metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
    attachments = [(a.name, a.media_type, a.log_time, a.data) for a in reader.iter_attachments()]
    s = summary.statistics
    stats = (
        s.message_count,
        dict(s.channel_message_counts),
        s.message_start_time,
        s.message_end_time,
        s.schema_count,
        s.channel_count,
        s.metadata_count,
        s.attachment_count,
    )
    channels = {
        c.id: (c.topic, c.message_encoding, c.metadata, summary.schemas[c.schema_id].data)
        for c in summary.channels.values()
    }
    return messages, in_time_order, metadata, attachments, stats, channels


def test_bulk_writer_reads_back_like_mcap_writer():
    rng = np.random.default_rng(3)
    variable = [rng.bytes(int(n)) for n in rng.integers(0, 3000, 40)]
    fixed = rng.integers(0, 256, (700, 37), dtype=np.uint8)

    def calls(w, b):
        for x in (w, b):
            x.add_metadata("run", {"a": "1"})
        w.add_attachment(create_time=5, log_time=7, name="c.toml", media_type="application/toml", data=b"x = 1")
        b.add_attachment("c.toml", "application/toml", b"x = 1", log_time=7, create_time=5)
        s1, s2 = w.register_schema("A", "protobuf", b"schema-a"), b.add_schema("A", "protobuf", b"schema-a")
        c1 = w.register_channel("/blocks", "protobuf", s1, {"k": "v"})
        c2 = b.add_channel("/blocks", "protobuf", s2, {"k": "v"})
        d1 = w.register_channel("/preview", "protobuf", s1)
        d2 = b.add_channel("/preview", "protobuf", s2)
        seq = 0
        for j in range(4):  # interleaved: variable-size messages, then a batch of fixed-size ones
            for i, payload in enumerate(variable[10 * j : 10 * j + 10]):
                t = 10**9 * j + 1000 * i
                w.add_message(c1, log_time=t, data=payload, publish_time=t, sequence=seq)
                b.add_message(c2, t, seq, [payload[:5], np.frombuffer(payload[5:], np.uint8)])
                seq += 1
            rows = fixed[175 * j : 175 * j + 175]
            times = 10**9 * j + 7 * np.arange(175, dtype=np.uint64) + 1  # no ties with the others
            for t, payload in zip(times.tolist(), rows):
                w.add_message(d1, log_time=t, data=payload.tobytes(), publish_time=t, sequence=seq)
                seq += 1
            b.add_messages(d2, times, np.arange(seq - 175, seq), rows)
            if j == 1:
                w.flush()
                b.flush()
        for x in (w, b):
            x.add_metadata("outcome", {"status": "completed"})

    ref, ours = write_both(calls)
    assert content(ours) == content(ref)
    # several chunks, and batches of fixed-size messages split across them
    chunks = make_reader(io.BytesIO(ours)).get_summary().chunk_indexes
    assert len(chunks) > 20 and max(c.uncompressed_size for c in chunks) < 4096 + 3100


def test_message_indexes_and_summary_crc_follow_the_spec(tmp_path):
    """Every chunk carries the CRC of its records, every message index entry points at a message
    of its channel with its log time, every message of both topics (thinned here, so that both
    are written) is indexed exactly once, in chunks of its topic alone; chunk indexes point at
    their chunks; the footer's CRC covers the summary and the footer's start (MCAP spec:
    Footer.summary_crc)."""
    path = tmp_path / "run.mcap"
    signals = motor_run(fs=1000.0, duration=3.0)
    write_run(
        path, metadata={"run": {"point_id": "p"}}, fs=1000.0, signals=signals, outcome=COMPLETED, samples_hz=100.0
    )
    data = path.read_bytes()
    summary = make_reader(io.BytesIO(data)).get_summary()
    indexed = 0
    for index in summary.chunk_indexes:
        f = io.BytesIO(data)
        f.seek(index.chunk_start_offset)
        assert f.read(1)[0] == Opcode.CHUNK
        (length,) = struct.unpack("<Q", f.read(8))
        assert 9 + length == index.chunk_length
        chunk = Chunk.read(ReadDataStream(f))
        stream, size = get_chunk_data_stream(chunk, validate_crc=True)
        records = stream.read(size)
        assert size == index.uncompressed_size and len(chunk.data) == index.compressed_size
        op, _, first_channel, _, _ = struct.unpack_from("<BQHIQ", records, 0)
        assert op == Opcode.MESSAGE
        # @mcap/core's indexed reader (Foxglove's) refuses a chunk of messages without indexes
        assert set(index.message_index_offsets) == {first_channel} and index.message_index_length > 0
        assert chunk.uncompressed_crc == zlib.crc32(records) != 0  # 0 would mean "not computed"
        for channel_id, offset in index.message_index_offsets.items():
            f.seek(offset)
            opcode, _ = struct.unpack("<BQ", f.read(9))
            assert opcode == Opcode.MESSAGE_INDEX
            entries = MessageIndex.read(ReadDataStream(f))
            assert entries.channel_id == channel_id
            times = [t for t, _ in entries.records]
            assert times == sorted(times)
            for log_time, at in entries.records:
                op, _, channel, _, t = struct.unpack_from("<BQHIQ", records, at)
                assert (op, channel, t) == (Opcode.MESSAGE, channel_id, log_time)
            indexed += len(entries.records)
    assert indexed == summary.statistics.message_count == 3 + 300  # blocks + thinned samples
    footer_at = len(data) - 8 - 29
    assert data[footer_at] == Opcode.FOOTER
    footer = Footer.read(ReadDataStream(io.BytesIO(data[footer_at + 9 :])))
    expected = zlib.crc32(data[footer.summary_start : footer_at + 1 + 8 + 16])
    assert footer.summary_crc == expected


def test_run_log_written_by_mcap_writer_uncompressed_is_read(tmp_path):
    """The reader does not depend on our writer: a run log from ``mcap``'s Writer (schemas and
    channels inside chunks, no compression) reads back exactly."""
    signals = motor_run(duration=12.0)  # 2400 samples: three blocks
    names = list(signals)
    path = tmp_path / "other-writer.mcap"
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE, chunk_size=20_000)
        w.start()
        w.add_metadata("run", encode_record("run", {"fs": 200.0}))
        w.add_metadata("channels", encode_record("channels", {n: {"role": "signal", "unit": ""} for n in names}))
        sid = w.register_schema(log_schema.BLOCK_SCHEMA_NAME, "protobuf", log_schema.BLOCK_SCHEMA)
        cid = w.register_channel(log_schema.BLOCK_TOPIC, "protobuf", sid)
        prefixes = log_schema.signal_prefixes(names)
        for k in range(0, 2400, 1000):
            payload = log_schema.encode_block(k, 200.0, prefixes, [signals[n][k : k + 1000] for n in names])
            w.add_message(cid, log_time=k * 5_000_000, data=payload, publish_time=k * 5_000_000)
        w.add_metadata("outcome", encode_record("outcome", {**COMPLETED, "n_samples": 2400}))
        w.finish()
    log = read_run(path)
    assert not log.torn and log.n_samples == 2400 and log.fs == 200.0
    for name, values in signals.items():
        assert np.array_equal(bits(log.frame[name].to_numpy()), bits(values)), name


@pytest.mark.parametrize("n_samples", [5, 10**15])
def test_frame_ignores_a_wrong_size_hint(tmp_path, n_samples):
    """The outcome's n_samples only sizes the frame: blocks beyond it, or signals no channel
    names, still land in the frame, and a huge one allocates nothing the chunks cannot fill."""
    path = tmp_path / "hint.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("channels", encode_record("channels", {"y": {"role": "signal", "unit": ""}}))
        sid = w.register_schema(log_schema.BLOCK_SCHEMA_NAME, "protobuf", log_schema.BLOCK_SCHEMA)
        cid = w.register_channel(log_schema.BLOCK_TOPIC, "protobuf", sid)
        y, z = np.arange(30.0), -np.arange(30.0)
        for k in (0, 20):
            data = log_schema.encode_block(
                k, 10.0, log_schema.signal_prefixes(["y", "z"]), [y[k : k + 10], z[k : k + 10]]
            )
            w.add_message(cid, log_time=k * 100_000_000, data=data, publish_time=k * 100_000_000)
        w.add_metadata("outcome", encode_record("outcome", {**COMPLETED, "n_samples": n_samples}))
        w.finish()
    frame = read_run(path).frame
    assert list(frame.columns) == ["y", "z"] and len(frame) == 30
    expected = np.where((np.arange(30) >= 10) & (np.arange(30) < 20), np.nan, y)
    assert np.array_equal(frame["y"].to_numpy(), expected, equal_nan=True)
    assert np.array_equal(frame["z"].to_numpy(), -expected, equal_nan=True)


@settings(max_examples=60, deadline=None)
@given(
    n_signals=st.integers(1, 20),  # field numbers past 15 take two-byte tags
    n=st.integers(0, 12),
    data=st.data(),
)
def test_sample_encoding_agrees_with_protobuf(n_signals, n, data):
    """Doubles and floats, in any mix: the writer's rows are what the protobuf library reads and
    writes, and the reader's decoder gives back the values (a float field: the float32 rounding)."""
    names = [f"sig{j}" for j in range(n_signals)]
    layout = tuple(data.draw(st.lists(st.booleans(), min_size=n_signals, max_size=n_signals)))
    values = st.floats(allow_nan=True, allow_infinity=True, width=64)
    columns = [np.array(data.draw(st.lists(values, min_size=n, max_size=n)), dtype=np.float64) for _ in names]
    with np.errstate(over="ignore"):  # beyond float32's range: ±inf, as the writer stores it
        stored = [c.astype(np.float32).astype(np.float64) if single else c for c, single in zip(columns, layout)]
    schema_data = log_schema.samples_schema(names, layout)
    assert log_schema.float32_fields(schema_data, n_signals) == layout
    fdp = log_schema.descriptor_pb2.FileDescriptorSet.FromString(schema_data).file[0]
    cls = log_schema.message_class(fdp, log_schema.SAMPLES_SCHEMA_NAME)
    rows = log_schema.encode_samples(columns, layout)
    width = sum(5 if single else 9 for single in layout) + max(0, n_signals - 15)
    assert rows.shape == (n, width) and rows.dtype == np.uint8
    for k, row in enumerate(rows):
        msg = cls.FromString(row.tobytes())
        assert all(bits(getattr(msg, name)) == bits(c[k]) for name, c in zip(names, stored))
        if all(bits(c[k]) != 0 for c in stored):  # proto3 leaves +0.0 out
            assert msg.SerializeToString() == row.tobytes()
    # the reader's decoder: the writer's layout and the protobuf library's own encoding alike
    decoded = log_schema.decode_samples([row.tobytes() for row in rows], layout)
    assert np.array_equal(bits(decoded), bits(np.array(stored).reshape(n_signals, n)))
    generic = [cls(**{name: c[k] for name, c in zip(names, stored)}).SerializeToString() for k in range(n)]
    expected = np.array([[c[k] if bits(c[k]) != 0 else np.nan for k in range(n)] for c in stored])
    assert np.array_equal(
        bits(log_schema.decode_samples(generic, layout).reshape(n_signals, n)), bits(expected.reshape(n_signals, n))
    )


def _mcap_bytes(record) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()


_u64, _u32, _u16 = st.integers(0, 2**64 - 1), st.integers(0, 2**32 - 1), st.integers(0, 2**16 - 1)
_text = st.text(max_size=12)  # any Unicode: the length prefixes count UTF-8 bytes


@settings(max_examples=80, deadline=None)
@given(
    name=_text,
    mapping=st.dictionaries(_text, _text, max_size=5),
    numbers=st.lists(_u64, min_size=9, max_size=9),
    small=st.lists(_u32, min_size=5, max_size=5),
    channels=st.dictionaries(_u16, _u64, max_size=3),
    opcode=st.integers(0, 255),
)
def test_record_encoders_agree_with_mcap_records(name, mapping, numbers, small, channels, opcode):
    """:mod:`labrunner.logs.mcap_records` writes every record byte for byte as ``mcap.records``."""
    a, b, c, d, e, f, g, h, i = numbers
    assert mcap_records.metadata(name, mapping) == _mcap_bytes(Metadata(name=name, metadata=mapping))
    assert mcap_records.metadata_index(a, b, name) == _mcap_bytes(MetadataIndex(offset=a, length=b, name=name))
    assert mcap_records.chunk_index(a, b, c, d, channels, e, name, f, g) == _mcap_bytes(
        ChunkIndex(
            message_start_time=a,
            message_end_time=b,
            chunk_start_offset=c,
            chunk_length=d,
            message_index_offsets=channels,
            message_index_length=e,
            compression=name,
            compressed_size=f,
            uncompressed_size=g,
        )
    )
    schemas = small[0] % 2**16
    assert mcap_records.statistics(a, schemas, *small[1:], b, c, channels) == _mcap_bytes(
        Statistics(
            message_count=a,
            schema_count=schemas,
            channel_count=small[1],
            attachment_count=small[2],
            metadata_count=small[3],
            chunk_count=small[4],
            message_start_time=b,
            message_end_time=c,
            channel_message_counts=channels,
        )
    )
    assert mcap_records.summary_offset(opcode, h, i) == _mcap_bytes(
        SummaryOffset(group_opcode=opcode, group_start=h, group_length=i)
    )
    assert mcap_records.data_end(small[0]) == _mcap_bytes(DataEnd(data_section_crc=small[0]))
    assert mcap_records.footer(h, i, small[1]) == _mcap_bytes(
        Footer(summary_start=h, summary_offset_start=i, summary_crc=small[1])
    )


@settings(max_examples=30, deadline=None)
@given(
    sizes=st.lists(st.integers(0, 40), min_size=1, max_size=60),
    channels=st.lists(st.sampled_from([1, 2, 3]), min_size=60, max_size=60),
    fixed=st.booleans(),
)
def test_message_indexes_of_a_chunk_equal_those_mcap_writes(sizes, channels, fixed):
    """``message_indexes`` (how ``upgrade-logs`` indexes a copied chunk; messages of one size take
    a numpy path) gives the entries ``mcap``'s own writer wrote for the same chunk."""
    buffer = io.BytesIO()
    w = Writer(buffer, chunk_size=1 << 20, compression=CompressionType.NONE, use_chunking=True)
    w.start()
    sid = w.register_schema("s", "raw", b"")
    ids = [w.register_channel(f"/t{c}", "raw", sid) for c in (1, 2, 3)]
    for i, size in enumerate(sizes):
        w.add_message(
            ids[channels[i] - 1], log_time=1000 - i, data=bytes(8 if fixed else size), publish_time=0, sequence=i
        )
    w.finish()
    buffer.seek(0)
    records, written = None, {}
    for record in StreamReader(buffer, emit_chunks=True).records:
        if isinstance(record, Chunk):
            stream, size = get_chunk_data_stream(record)
            records = stream.read(size)
        elif isinstance(record, MessageIndex) and record.records:
            written[record.channel_id] = record.records
    # mcap's writer puts the schema and channels inside the chunk: index the messages after them
    start = records.index(bytes([Opcode.MESSAGE]) + struct.pack("<Q", 22 + (8 if fixed else sizes[0])))
    ours = message_indexes(records[start:])
    assert {c: [(int(t), int(o) + start) for t, o in e] for c, e in ours.items()} == written
    assert sorted(written) == sorted(ours)


def test_message_indexes_refuse_what_is_not_a_message():
    with pytest.raises(McapError, match="opcode"):
        message_indexes(bytes([Opcode.SCHEMA]) + struct.pack("<Q", 30) + bytes(30))
    with pytest.raises(McapError, match="inside a record"):
        message_indexes(bytes([Opcode.MESSAGE]) + struct.pack("<Q", 22))
