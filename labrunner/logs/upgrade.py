"""Rewriting a run log of format ``labrunner-3`` in the current layout, so that Foxglove opens it.

``labrunner-3`` logs (written 2026-12-03 … 12-04) store ``/run/samples`` in chunks without
message index records. MCAP allows that and :func:`labrunner.logs.read_run` reads them, but
@mcap/core's ``McapIndexedReader`` — the reader the Foxglove app opens a local file with —
refuses such a chunk. :func:`rewrite` copies every record of such a file into a new one: the
header, schemas, channels, attachments and metadata as they are (``run.log_format`` becomes the
current format), every chunk as it is (compressed data and CRC unchanged, no recompression)
followed by the message index of each channel in it, then a new summary. The samples are
therefore the very bytes they were; :func:`same_run` proves it by reading both files.
"""

from __future__ import annotations

import os
from typing import BinaryIO

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Chunk, DataEnd, Header, Metadata, Schema
from mcap.stream_reader import StreamReader

from labrunner.errors import LabrunnerError
from labrunner.logs.mcap_writer import BulkWriter
from labrunner.logs.reader import RunLog, read_run
from labrunner.logs.writer import LOG_FORMAT

#: The format whose logs :func:`rewrite` upgrades (no other labrunner format lacks message indexes).
OLD_FORMAT = "labrunner-3"


class UpgradeError(LabrunnerError):
    """A log that cannot be rewritten, or whose rewrite does not read back as the same run."""


def unindexed_messages(path: str | os.PathLike[str]) -> int:
    """How many messages of the finished log at ``path`` no message index lists (those of the
    channels no chunk indexes; at least 1 if any chunk of messages lacks indexes: the chunks
    @mcap/core's indexed reader refuses), from the summary alone; 0: the file needs no upgrade.
    McapError (or another read error) for a file without a readable summary."""
    with open(path, "rb") as f:
        summary = SeekingReader(f).get_summary()
    if summary is None:
        raise McapError("no summary")
    bare = sum(1 for c in summary.chunk_indexes if c.message_index_length == 0 and c.message_end_time)
    if not bare:
        return 0
    indexed = {cid for c in summary.chunk_indexes for cid in c.message_index_offsets}
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    return sum(n for cid, n in counts.items() if cid not in indexed) or bare


def rewrite(source: str | os.PathLike[str], target: BinaryIO) -> None:
    """Write the finished log at ``source`` into ``target`` in the current layout (see the
    module); UpgradeError for a file that is torn or was not written by labrunner's writer."""
    with open(source, "rb") as f:
        out = BulkWriter(target)
        try:
            for record in StreamReader(f, emit_chunks=True, validate_crcs=True).records:
                if isinstance(record, Header):
                    out.start(record.library, record.profile)
                elif isinstance(record, Schema):
                    _same_id("schema", record.id, out.add_schema(record.name, record.encoding, record.data))
                elif isinstance(record, Channel):
                    added = out.add_channel(record.topic, record.message_encoding, record.schema_id, record.metadata)
                    _same_id("channel", record.id, added)
                elif isinstance(record, Metadata):
                    out.add_metadata(record.name, _current(record))
                elif isinstance(record, Attachment):
                    out.add_attachment(
                        record.name,
                        record.media_type,
                        record.data,
                        log_time=record.log_time,
                        create_time=record.create_time,
                    )
                elif isinstance(record, Chunk):
                    out.copy_chunk(record)
                elif isinstance(record, DataEnd):
                    break  # the summary is written anew; message indexes are written with their chunks
            else:
                raise UpgradeError(f"{os.fspath(source)}: torn (no data end record): nothing to upgrade")
        except McapError as exc:
            raise UpgradeError(f"{os.fspath(source)}: cannot be rewritten: {exc}") from None
        out.finish()


def _same_id(kind: str, stored: int, added: int) -> None:
    if stored != added:
        raise McapError(f"{kind} ids are not 1, 2, … in file order ({kind} {stored} found as number {added})")


def _current(record: Metadata) -> dict[str, str]:
    """A metadata record's entries, ``run.log_format`` set to the current format if it was OLD_FORMAT."""
    if record.name == "run" and record.metadata.get("log_format") == OLD_FORMAT:
        return {**record.metadata, "log_format": LOG_FORMAT}
    return record.metadata


def same_run(old: RunLog, path: str | os.PathLike[str]) -> None:
    """Raise UpgradeError unless the log at ``path`` reads back as ``old`` does: the same samples
    bit for bit (NaN payloads included), signals, rate, records (``run.log_format`` aside),
    outcome, channels and attachments, neither torn nor damaged."""
    new = read_run(path)
    where = os.fspath(path)
    if new.torn or new.damaged:
        raise UpgradeError(f"{where}: the rewritten log reads back {'torn' if new.torn else new.damaged}")
    if new.names != old.names or new.data.shape != old.data.shape:
        raise UpgradeError(f"{where}: the rewritten log holds signals {new.names} × {new.data.shape[1]} samples")
    if not np.array_equal(new.data.view(np.uint64), old.data.view(np.uint64)):
        raise UpgradeError(f"{where}: the rewritten log's samples differ from the original's")
    records = {name: dict(r) for name, r in new.metadata.items()}
    records.get("run", {}).pop("log_format", None)
    before = {name: dict(r) for name, r in old.metadata.items()}
    before.get("run", {}).pop("log_format", None)
    # compared as text: a NaN metric equals itself there, and the order of every record is kept
    same = repr((new.fs, records, new.outcome, new.channels, new.attachments)) == repr(
        (old.fs, before, old.outcome, old.channels, old.attachments)
    )
    if not same:
        raise UpgradeError(f"{where}: the rewritten log's records differ from the original's")
