"""The MCAP records a run log writes per file, encoded with :mod:`struct` in one call each.

``mcap.records``' classes encode a record field by field through a ``RecordBuilder`` (about ten
Python calls per field); a motor run's file has eleven such records (its own metadata, the
outcome, the summary), which cost a third of the file's write time that way. The layouts here
are those of the MCAP spec (v0) as ``mcap.records`` writes them: opcode (u8), record length
(u64), then the fields little-endian, strings and byte arrays prefixed by their u32 length, maps
and arrays by their u32 byte length. ``tests/test_logs_mcap.py`` checks every function byte for
byte against ``mcap``'s own classes.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping

from mcap.opcode import Opcode

_RECORD = struct.Struct("<BQ")  # opcode, record length
_U32 = struct.Struct("<I")
_CHANNEL_U64 = struct.Struct("<HQ")  # a map entry channel id → offset or count
_CHUNK_INDEX = struct.Struct("<BQQQQQ")  # + start and end time, chunk offset, chunk length
_CHUNK_INDEX_TAIL = struct.Struct("<Q")  # message index length; then compression, sizes
_SIZES = struct.Struct("<QQ")
_METADATA_INDEX = struct.Struct("<BQQQ")  # + offset, length; then the name
_STATISTICS = struct.Struct("<BQQHIIIIQQI")
_SUMMARY_OFFSET = struct.Struct("<BQBQQ")
_DATA_END = struct.Struct("<BQI")
_FOOTER = struct.Struct("<BQQQI")


def string(value: str) -> bytes:
    """An MCAP string: u32 byte length and UTF-8."""
    data = value.encode()
    return _U32.pack(len(data)) + data


def _record(opcode: int, body: bytes) -> bytes:
    return _RECORD.pack(opcode, len(body)) + body


def metadata(name: str, data: Mapping[str, str]) -> bytes:
    """A Metadata record: name, then the map of strings."""
    entries = b"".join([string(k) + string(v) for k, v in data.items()])
    return _record(Opcode.METADATA, string(name) + _U32.pack(len(entries)) + entries)


def metadata_index(offset: int, length: int, name: str) -> bytes:
    """A MetadataIndex record: where a Metadata record of ``name`` starts and its length [bytes]."""
    name_bytes = string(name)
    return _METADATA_INDEX.pack(Opcode.METADATA_INDEX, 16 + len(name_bytes), offset, length) + name_bytes


def chunk_index(
    start_time: int,
    end_time: int,
    chunk_start: int,
    chunk_length: int,
    index_offsets: Mapping[int, int],
    index_length: int,
    compression: str,
    compressed_size: int,
    uncompressed_size: int,
) -> bytes:
    """A ChunkIndex record (``index_offsets``: channel id → offset of its MessageIndex record)."""
    offsets = b"".join([_CHANNEL_U64.pack(c, o) for c, o in index_offsets.items()])
    tail = (
        _U32.pack(len(offsets))
        + offsets
        + _CHUNK_INDEX_TAIL.pack(index_length)
        + string(compression)
        + _SIZES.pack(compressed_size, uncompressed_size)
    )
    head = _CHUNK_INDEX.pack(Opcode.CHUNK_INDEX, 32 + len(tail), start_time, end_time, chunk_start, chunk_length)
    return head + tail


def statistics(
    message_count: int,
    schema_count: int,
    channel_count: int,
    attachment_count: int,
    metadata_count: int,
    chunk_count: int,
    start_time: int,
    end_time: int,
    channel_counts: Mapping[int, int],
) -> bytes:
    """A Statistics record (``channel_counts``: channel id → message count)."""
    counts = b"".join([_CHANNEL_U64.pack(c, n) for c, n in channel_counts.items()])
    length = _STATISTICS.size - _RECORD.size + len(counts)
    fields = (message_count, schema_count, channel_count, attachment_count, metadata_count, chunk_count)
    return _STATISTICS.pack(Opcode.STATISTICS, length, *fields, start_time, end_time, len(counts)) + counts


def summary_offset(group_opcode: int, group_start: int, group_length: int) -> bytes:
    """A SummaryOffset record: where the summary's group of ``group_opcode`` records lies."""
    return _SUMMARY_OFFSET.pack(Opcode.SUMMARY_OFFSET, 17, group_opcode, group_start, group_length)


def data_end(data_section_crc: int = 0) -> bytes:
    """The DataEnd record (CRC 0: not computed)."""
    return _DATA_END.pack(Opcode.DATA_END, 4, data_section_crc)


def footer(summary_start: int, summary_offset_start: int, summary_crc: int) -> bytes:
    """The Footer record."""
    return _FOOTER.pack(Opcode.FOOTER, 20, summary_start, summary_offset_start, summary_crc)
