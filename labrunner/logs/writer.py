"""Writing one run to one MCAP file: streaming (:class:`RunLogWriter`) or at once (:func:`write_run`).

File layout, in order (zstd chunks, full MCAP indexes and summary; written by
:class:`labrunner.logs.mcap_writer.BulkWriter`):

1. the part every run of a batch shares, a :class:`LogPrefix` encoded once and copied as bytes
   into each file: header; metadata ``channels`` (per signal: ``role``, ``unit``) and any shared
   caller records (e.g. ``rig``); attachments (e.g. the campaign file); the schemas and
   channels;
2. the run's own metadata: ``run`` (caller's record plus ``fs`` [Hz], ``labrunner_version``,
   ``log_format`` and the per-sample channel's rate), then ``config`` and any further caller
   records (``parameters``, ``metrics``, a ``diagnostics`` record, ...); **flushed**, so even a
   file killed before its first sample names its run and its topics;
3. chunks of ``/run/samples`` messages, each sample stored once (and, only when ``[logging]
   samples_hz`` thins them, ``/run/blocks`` in chunks of their own; see
   :mod:`labrunner.logs.schema`), each chunk followed by its message index (which Foxglove's
   reader requires), flushed every ``flush_interval_s`` of wall time, so a killed writer leaves a
   file whose complete chunks :func:`labrunner.logs.read_run` salvages;
4. metadata ``outcome`` (the caller's outcome plus ``n_samples``), after the last chunk: a file
   without it did not finish;
5. summary and footer. A file without a footer is *torn*.

Every message's ``log_time`` is the wall-clock time of its (first) sample: the run's start
(``start_time``, s since 1970) plus k / f_s, so a viewer places runs on the calendar and the times
only grow; a sample's ``sequence`` is its index k.

Metadata values are plain text (:mod:`labrunner.logs.metadata_text`).
"""

from __future__ import annotations

import copy
import io
import json
import math
import os
import time
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding

from labrunner import safefs
from labrunner.errors import InvalidParameter, LabrunnerError, check_finite
from labrunner.logs import schema
from labrunner.logs.mcap_writer import BulkWriter, Prefix, message_row, repeat_row
from labrunner.logs.metadata_text import encode_record
from labrunner.version import __version__

ROLES = ("input", "output", "controlled", "reference", "error", "estimate", "signal")
STATUSES = ("completed", "aborted", "no-motion", "failed")  # engine.RunResult.outcome["status"]
RESERVED_RECORDS = ("channels", "outcome")
# run.log_format: each sample once in /run/samples (sequence = k), every chunk with its message
# indexes; labrunner-3 was the same without the samples' indexes (upgraded by labrunner.logs.upgrade)
LOG_FORMAT = "labrunner-4"
PLAIN_FORMATS = ("labrunner-2", "labrunner-3", LOG_FORMAT)  # plain-text metadata (2: blocks and samples both)
_ROLE_GROUPS = {f"{role}s" if role != "controlled" else role: role for role in ROLES}
_MEDIA_TYPES = {".toml": "application/toml", ".json": "application/json", ".txt": "text/plain"}


def infer_role(name: str) -> str:
    """Role of a signal from the engine's naming (``ref_<y>``, ``e_<y>``, ``<estimate>_<y>``)."""
    if name.startswith("ref_"):
        return "reference"
    if "_hat" in name:  # before e_: ``e_hat_<y>`` is the filtered error, an estimate
        return "estimate"
    if name.startswith("e_"):
        return "error"
    return "signal"


def normalise_channels(
    channels: Mapping[str, Any] | Sequence[str] | None, names: Sequence[str] | None = None
) -> dict[str, dict[str, Any]]:
    """``{signal: {"role": ..., "unit": ..., ...}}`` from any of the accepted forms.

    Accepted: a sequence of names (roles inferred); per signal ``{name: {"role", "unit"}}``;
    grouped ``{"outputs": [...], "inputs": [...], ..., "units": {name: unit}}`` (the engine's
    ``RunResult.channels``). With ``names`` (the signals actually written), every name must be
    described or inferable and no other name may appear; the order follows ``names``.
    """
    given: dict[str, dict[str, Any]] = {}
    if channels is None:
        channels = {}
    if (
        isinstance(channels, Mapping)
        and channels
        and all(not isinstance(v, Mapping) for k, v in channels.items() if k != "units")
    ):
        units = channels.get("units", {})
        for group, members in channels.items():
            if group == "units":
                continue
            if group not in _ROLE_GROUPS:
                raise InvalidParameter(f"channels.{group}", f"must be one of {sorted(_ROLE_GROUPS)} or 'units'")
            for name in members:
                given[name] = {"role": _ROLE_GROUPS[group], "unit": str(units.get(name, ""))}
    elif isinstance(channels, Mapping):
        for name, info in channels.items():
            given[name] = {"role": infer_role(name), "unit": "", **dict(info)}
    else:
        given = {name: {"role": infer_role(name), "unit": ""} for name in channels}
    for name, info in given.items():
        if info["role"] not in ROLES:
            raise InvalidParameter(f"channels.{name}.role", f"must be one of {list(ROLES)}, got {info['role']!r}")
    if names is None:
        schema.check_signal_names(list(given))
        return given
    schema.check_signal_names(list(names))
    extra = sorted(set(given) - set(names))
    if extra:
        raise InvalidParameter("channels", f"describe signals that are not written: {extra}")
    return {name: given.get(name, {"role": infer_role(name), "unit": ""}) for name in names}


def _positive(name: str, value: float) -> float:
    value = check_finite(name, value)
    if value <= 0:
        raise InvalidParameter(name, f"must be > 0 Hz, got {value}")
    return value


class LogPrefix:
    """What every run log of a batch shares, encoded once: header, ``channels`` and ``shared``
    records, attachments, schemas and channels (see the module's docstring).

    ``samples_hz`` thins the per-sample channel ``/run/samples`` to every ⌈f_s / samples_hz⌉-th
    sample (None: every sample); the channel's metadata says so (``decimation``, ``rate_hz``), and
    only then is every sample also kept, in ``/run/blocks``. ``float32`` names the signals stored
    as float32 (their values are rounded to it on writing, in ``/run/blocks`` too; a device's
    samples are float32 already, so nothing changes), the rest as float64. ``log_format``
    ``labrunner-3`` writes that format's layout (``/run/samples`` without message indexes, which
    Foxglove's reader refuses): only to make old logs for the tests and benchmarks of
    :mod:`labrunner.logs.upgrade`.
    """

    def __init__(
        self,
        *,
        fs: float,
        channels: Mapping[str, Any] | Sequence[str],
        shared: Mapping[str, Mapping[str, Any]] | None = None,
        attachments: Mapping[str, bytes] | None = None,
        samples_hz: float | None = None,
        created: float | None = None,
        float32: Collection[str] = (),
        log_format: str = LOG_FORMAT,
    ) -> None:
        self.fs = _positive("fs", fs)
        if log_format not in (LOG_FORMAT, "labrunner-3"):
            raise InvalidParameter("log_format", f"must be {LOG_FORMAT!r} or 'labrunner-3', got {log_format!r}")
        self.log_format = log_format
        if samples_hz is not None and not _positive("samples_hz", samples_hz) <= self.fs:
            raise InvalidParameter("samples_hz", f"must be in (0, fs = {self.fs:g}] Hz, got {samples_hz}")
        self.channels = normalise_channels(channels)
        self.names = list(self.channels)
        self.decimation = 1 if samples_hz is None else max(1, math.ceil(self.fs / samples_hz - 1e-9))
        self.samples_hz = self.fs / self.decimation
        shared = dict(shared or {})
        if not all(isinstance(r, Mapping) for r in shared.values()):
            raise InvalidParameter("metadata", "shared records must map record names to mappings")
        self.shared_names = tuple(shared)
        units = [str(info.get("unit") or "") for info in self.channels.values()]
        self.fields = schema.sample_fields(self.names, units)
        unknown = sorted(set(float32) - set(self.names))
        if unknown:
            raise InvalidParameter("float32", f"names signals that are not logged: {unknown}")
        self.layout: schema.Layout = tuple(name in float32 for name in self.names)
        self.float32 = frozenset(name for name, single in zip(self.names, self.layout) if single)
        self._tags = schema.sample_tags(self.layout)
        self.prefixes = schema.signal_prefixes(self.names)
        created_ns = round((time.time() if created is None else created) * 1e9)
        buffer = io.BytesIO()
        mcap = BulkWriter(buffer)
        mcap.start(library=f"labrunner/{__version__}")
        mcap.add_metadata("channels", encode_record("channels", self.channels))
        for name, record in shared.items():
            mcap.add_metadata(name, encode_record(name, record))
        for name, data in (attachments or {}).items():
            media = _MEDIA_TYPES.get(Path(name).suffix, "application/octet-stream")
            mcap.add_attachment(str(name), media, bytes(data), log_time=created_ns, create_time=created_ns)
        self.block_channel: int | None = None  # /run/blocks: only when the samples are thinned
        if self.decimation > 1:
            block_schema = mcap.add_schema(schema.BLOCK_SCHEMA_NAME, SchemaEncoding.Protobuf, schema.BLOCK_SCHEMA)
            self.block_channel = mcap.add_channel(schema.BLOCK_TOPIC, MessageEncoding.Protobuf, block_schema)
        sample_schema = mcap.add_schema(
            schema.SAMPLES_SCHEMA_NAME, SchemaEncoding.Protobuf, schema.samples_schema(self.fields, self.layout)
        )
        channel_meta = {
            "rate_hz": repr(self.samples_hz),
            "decimation": str(self.decimation),
            "time": "log_time: wall-clock time of the sample; sequence: its index k (t = k / fs)",
            **{f"unit.{f}": u for f, u in zip(self.fields, units) if u},
        }
        # indexed like every channel (16 uncompressed bytes a sample): @mcap/core's indexed reader, the
        # one the Foxglove app opens a local file with, refuses a chunk without message indexes
        self.samples_channel = mcap.add_channel(
            schema.SAMPLES_TOPIC,
            MessageEncoding.Protobuf,
            sample_schema,
            channel_meta,
            indexed=log_format == LOG_FORMAT,
        )
        self.encoded: Prefix = mcap.prefix()
        self._sample_row = message_row(self.samples_channel, self._tags.dtype, self._tags)

    def sample_records(self, n: int) -> np.ndarray:
        """An empty :func:`~labrunner.logs.mcap_writer.message_array` for ``n`` samples."""
        return repeat_row(self._sample_row, n)

    def describe_samples(self) -> str:
        """What ``/run/samples`` holds, for the ``run`` record."""
        if self.decimation == 1:
            text = f"every sample ({self.fs:g} Hz)"
        else:
            text = (
                f"every {self.decimation}th sample ({self.samples_hz:g} Hz of {self.fs:g} Hz, thinned by "
                "[logging] samples_hz); /run/blocks keeps every sample"
            )
        singles = [name for name in self.names if name in self.float32]
        if singles:
            text += f"; float32: {', '.join(singles)}"
        return text


class RunLogWriter:
    """Stream one run into an MCAP file (real rigs), block by block; use as a context manager.

    ``metadata`` maps record names to mappings (``run``, ``config``, ...); ``prefix`` is the batch's
    shared part (or give ``fs``, ``channels``, ``attachments``, ``samples_hz``, ``float32`` and one
    is made);
    ``start_time`` [s since 1970] is the wall-clock time of sample 0 (default: now). Each
    :meth:`write_block` call writes n per-sample messages (and ⌈n / 1000⌉ block messages where
    the samples are thinned), so pass
    blocks of ~0.1 s rather than single samples. The file is flushed after the metadata and then at
    the first block after every ``flush_interval_s`` (0: after every block); what was flushed
    survives a SIGKILL. Leaving the ``with`` block without :meth:`finish` (an exception, Ctrl-C)
    still closes the file cleanly, outcome ``failed``.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: Mapping[str, Mapping[str, Any]],
        prefix: LogPrefix | None = None,
        fs: float | None = None,
        channels: Mapping[str, Any] | Sequence[str] | None = None,
        attachments: Mapping[str, bytes] | None = None,
        samples_hz: float | None = None,
        start_time: float | None = None,
        flush_interval_s: float = 0.25,
        float32: Collection[str] = (),
    ) -> None:
        if prefix is None:
            if fs is None or channels is None:
                raise InvalidParameter("prefix", "give a LogPrefix, or fs and channels")
            prefix = LogPrefix(
                fs=fs, channels=channels, attachments=attachments, samples_hz=samples_hz, float32=float32
            )
        self.prefix = prefix
        self.fs, self.names, self.decimation = prefix.fs, prefix.names, prefix.decimation
        self.flush_interval_s = check_finite("flush_interval_s", flush_interval_s)
        if self.flush_interval_s < 0:
            raise InvalidParameter("flush_interval_s", f"must be >= 0 s, got {flush_interval_s}")
        start = time.time() if start_time is None else check_finite("start_time", start_time)
        self.start_ns = round(start * 1e9)
        records = self._records(metadata)
        self.n_samples = 0
        self._finished = False
        # never through a planted link or FIFO (labrunner.safefs); closed in finish()
        self._file = os.fdopen(safefs.open_fd(Path(path), os.O_WRONLY | os.O_CREAT | os.O_TRUNC), "wb")
        self._mcap = BulkWriter(self._file)
        self._mcap.resume(prefix.encoded)
        for name, record in records.items():
            self._mcap.add_metadata(name, record)
        self._mcap.flush()
        self._last_flush = time.monotonic()

    def _records(self, metadata: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, str]]:
        if not isinstance(metadata, Mapping):
            raise InvalidParameter("metadata", f"must map record names to mappings, got {type(metadata).__name__}")
        reserved = sorted(set(metadata) & {*RESERVED_RECORDS, *self.prefix.shared_names})
        if reserved:
            raise InvalidParameter(
                "metadata", f"record names {reserved} are written by the logger or shared by the batch"
            )
        run = metadata.get("run", {})
        if not isinstance(run, Mapping):
            raise InvalidParameter("metadata.run", f"must be a mapping, got {type(run).__name__}")
        run = {**run, "fs": self.fs, "log_format": self.prefix.log_format, "samples": self.prefix.describe_samples()}
        run.setdefault("labrunner_version", __version__)
        records = {"run": encode_record("run", run)}
        records.update({name: encode_record(name, rec) for name, rec in metadata.items() if name != "run"})
        return records

    def write_block(self, first_index: int, block: Mapping[str, np.ndarray]) -> None:
        """Append samples ``first_index .. first_index + n - 1`` of every signal (n ≥ 0)."""
        if self._finished:
            raise LabrunnerError("run log already finished")
        if block.keys() != set(self.names):
            missing, extra = sorted(set(self.names) - set(block)), sorted(set(block) - set(self.names))
            raise InvalidParameter("block", f"signals must match the channels; missing {missing}, unknown {extra}")
        with np.errstate(over="ignore"):  # a float32 signal beyond ±3.4e38 is ±inf
            columns = [
                np.asarray(block[name], dtype=np.float32 if single else np.float64).astype(np.float64, copy=False)
                for name, single in zip(self.names, self.prefix.layout)
            ]
        n = columns[0].shape[0] if columns[0].ndim == 1 else -1
        if any(c.ndim != 1 or c.shape[0] != n for c in columns):
            shapes = {name: c.shape for name, c in zip(self.names, columns)}
            raise InvalidParameter("block", f"signals must be 1-D arrays of one length, got {shapes}")
        first_index = int(first_index)
        if first_index < self.n_samples:
            raise InvalidParameter(
                "first_index", f"must be >= {self.n_samples} (samples already written), got {first_index}"
            )
        channel = self.prefix.block_channel
        for start in range(0, n if channel is not None else 0, schema.BLOCK_SAMPLES):
            k = first_index + start
            parts = schema.block_parts(
                k, self.fs, self.prefix.prefixes, [c[start : start + schema.BLOCK_SAMPLES] for c in columns]
            )
            self._mcap.add_message(channel, self.start_ns + round(k * 1e9 / self.fs), k, parts)
        self._write_samples(first_index, n, columns)
        self.n_samples = max(self.n_samples, first_index + n)
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self._mcap.flush()
            self._last_flush = time.monotonic()

    def _write_samples(self, first_index: int, n: int, columns: list[np.ndarray]) -> None:
        """One ``/run/samples`` message per kept sample, built in place in one record array."""
        step = self.decimation
        offset = (-first_index) % step
        count = len(range(offset, n, step))
        if not count:
            return
        k = np.arange(first_index + offset, first_index + n, step, dtype=np.uint64)
        records = self.prefix.sample_records(count)
        records["log_time"] = np.rint(k * (1e9 / self.fs)).astype(np.uint64) + np.uint64(self.start_ns)
        records["sequence"] = k  # the sample's index: its time is k / fs
        schema.fill_samples(records["data"], [c[offset::step] for c in columns] if step > 1 else columns)
        self._mcap.add_records(self.prefix.samples_channel, records)

    def finish(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome as the final metadata record, the summary and the footer; close."""
        if self._finished:
            raise LabrunnerError("run log already finished")
        if not isinstance(outcome, Mapping) or outcome.get("status") not in STATUSES:
            status = outcome.get("status") if isinstance(outcome, Mapping) else outcome
            raise InvalidParameter("outcome.status", f"must be one of {list(STATUSES)}, got {status!r}")
        record = encode_record("outcome", {**outcome, "n_samples": self.n_samples})
        self._finished = True
        try:
            self._mcap.flush()  # the last chunks go before the outcome
            self._mcap.add_metadata("outcome", record)
            self._mcap.finish()
        finally:
            self._file.close()

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if self._finished:
            return
        if exc_type is None:
            message = "run log closed without an outcome"
        else:
            message = f"{exc_type.__name__}: {exc}"
        self.finish({"status": "failed", "message": message})


def write_run(
    path: str | os.PathLike[str],
    *,
    metadata: Mapping[str, Mapping[str, Any]],
    signals: Mapping[str, np.ndarray],
    outcome: Mapping[str, Any],
    prefix: LogPrefix | None = None,
    fs: float | None = None,
    attachments: Mapping[str, bytes] | None = None,
    channels: Mapping[str, Any] | Sequence[str] | None = None,
    samples_hz: float | None = None,
    start_time: float | None = None,
    float32: Collection[str] = (),
) -> None:
    """Write a finished run (all signals of one length K, sample k at k / fs) to ``path``; with a
    batch's ``prefix`` (whose signals must be these), ``fs``, ``channels``, ``attachments``,
    ``samples_hz`` and ``float32`` come from it."""
    if prefix is None:
        if fs is None:
            raise InvalidParameter("fs", "is required without a LogPrefix")
        described = normalise_channels(channels, list(signals))
        prefix = LogPrefix(fs=fs, channels=described, attachments=attachments, samples_hz=samples_hz, float32=float32)
    elif list(signals) != prefix.names:
        raise InvalidParameter("signals", f"must be the prefix's {prefix.names}, got {list(signals)}")
    with RunLogWriter(path, metadata=metadata, prefix=prefix, start_time=start_time) as writer:
        writer.write_block(0, signals)
        writer.finish(outcome)


@dataclass
class BatchPrefixes:
    """The :class:`LogPrefix` of each distinct set of signals in a batch (usually one), so that a
    worker encodes the shared part of its logs once per batch."""

    fs: float
    shared: Mapping[str, Mapping[str, Any]]
    attachments: Mapping[str, bytes]
    samples_hz: float | None = None

    def __post_init__(self) -> None:
        self._made: dict[str, LogPrefix] = {}
        # (signals, channels as given, prefix): a run whose signals and description equal an earlier
        # one's gets its prefix by one comparison, not by describing its channels again (~15 µs a run)
        self._seen: list[tuple[tuple[str, ...], Any, LogPrefix]] = []

    def get(
        self,
        signals: Sequence[str],
        channels: Mapping[str, Any] | Sequence[str] | None,
        float32: Collection[str] = (),
    ) -> LogPrefix:
        """The prefix of runs logging ``signals`` described by ``channels``, ``float32`` of them as
        float32 (:class:`LogPrefix`)."""
        names, singles = tuple(signals), frozenset(float32)
        for seen_names, seen_channels, prefix in self._seen:
            if names == seen_names and channels == seen_channels and singles == set(prefix.float32):
                return prefix
        described = normalise_channels(channels, list(names))
        key = json.dumps([described, sorted(singles)], sort_keys=False)
        if key not in self._made:
            self._made[key] = LogPrefix(
                fs=self.fs,
                channels=described,
                shared=self.shared,
                attachments=self.attachments,
                samples_hz=self.samples_hz,
                float32=singles,
            )
        self._seen.append((names, copy.deepcopy(channels), self._made[key]))
        return self._made[key]
