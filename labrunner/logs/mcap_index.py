"""The message index of a chunk: where each message of each channel lies in the chunk's
uncompressed records, and its log time — what MCAP's MessageIndex records hold, and what
:meth:`labrunner.logs.mcap_writer.BulkWriter.copy_chunk` writes after a chunk it copies from a
file that had none (``labrunner upgrade-logs``)."""

from __future__ import annotations

import functools
import struct

import numpy as np
from mcap.exceptions import McapError
from mcap.opcode import Opcode

#: One MessageIndex entry: log time [ns] and offset of the message's record in the chunk.
INDEX_ENTRY = np.dtype([("log_time", "<u8"), ("offset", "<u8")])
_RECORD_LENGTH = struct.Struct("<Q")
#: A message record's header: opcode, record length, channel, sequence, log and publish time [ns].
MESSAGE_HEADER = struct.Struct("<BQHIQQ")


def message_indexes(records: bytes | memoryview) -> dict[int, np.ndarray]:
    """The message index of a chunk's uncompressed ``records``: channel id → :data:`INDEX_ENTRY`
    rows (log time, offset of the message's record), channels in order of first appearance.
    McapError for a record that is not a message or runs past the end."""
    fixed = _fixed_size_indexes(records)
    if fixed is not None:
        return fixed
    found: dict[int, list[tuple[int, int]]] = {}
    pos, end = 0, len(records)
    while pos < end:
        if pos + MESSAGE_HEADER.size > end:
            raise McapError(f"chunk records end inside a record at offset {pos}")
        opcode, length, channel_id, _, log_time, _ = MESSAGE_HEADER.unpack_from(records, pos)
        if opcode != Opcode.MESSAGE or pos + 9 + length > end:
            raise McapError(f"chunk holds a record of opcode {opcode:#x} at offset {pos}, not a whole message")
        found.setdefault(channel_id, []).append((log_time, pos))
        pos += 9 + length
    return {channel_id: np.array(entries, dtype=INDEX_ENTRY) for channel_id, entries in found.items()}


def _fixed_size_indexes(records: bytes | memoryview) -> dict[int, np.ndarray] | None:
    """:func:`message_indexes` of records that are all messages of one size (this writer's
    chunks), read as one numpy array (~60× faster than record by record); None for any other."""
    if len(records) < MESSAGE_HEADER.size:
        return None
    size = 9 + _RECORD_LENGTH.unpack_from(records, 1)[0]
    if size < MESSAGE_HEADER.size or len(records) % size:
        return None
    rows = np.frombuffer(records, dtype=_message_header_dtype(size))
    if not ((rows["opcode"] == Opcode.MESSAGE).all() and (rows["length"] == size - 9).all()):
        return None
    channels, first = np.unique(rows["channel"], return_index=True)
    offsets = size * np.arange(len(rows), dtype=np.uint64)
    indexes = {}
    for channel_id in channels[np.argsort(first)]:
        mine = rows["channel"] == channel_id
        entries = np.empty(int(mine.sum()), dtype=INDEX_ENTRY)
        entries["log_time"], entries["offset"] = rows["log_time"][mine], offsets[mine]
        indexes[int(channel_id)] = entries
    return indexes


@functools.lru_cache(maxsize=16)
def _message_header_dtype(size: int) -> np.dtype:
    """A message record of ``size`` bytes: its header's fields, the payload skipped."""
    return np.dtype(
        {
            "names": ["opcode", "length", "channel", "log_time"],
            "formats": ["u1", "<u8", "<u2", "<u8"],
            "offsets": [0, 1, 9, 15],
            "itemsize": size,
        }
    )
