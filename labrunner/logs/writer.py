"""Writing one run to one MCAP file: streaming (:class:`RunLogWriter`) or at once (:func:`write_run`).

File layout, in order (zstd chunks, full MCAP indexes and summary; written by
:class:`labrunner.logs.mcap_writer.BulkWriter`, which takes a block's preview samples at once):

1. metadata ``run`` (caller's record plus ``fs`` [Hz] and ``labrunner_version``), ``config``
   (the resolved point), any further caller records, then ``channels`` (per signal: ``role``,
   ``unit``); attachments (e.g. the campaign file); the two schemas and channels; **flushed**, so
   even a file killed before its first sample names its run and its topics;
2. chunks of ``/run/blocks`` and ``/run/preview`` messages (see :mod:`labrunner.logs.schema`),
   flushed every ``flush_interval_s`` of wall time, so a killed writer leaves a file whose
   complete chunks :func:`labrunner.logs.read_run` salvages;
3. metadata ``outcome`` (the caller's outcome plus ``n_samples``), after the last chunk: a file
   without it did not finish;
4. summary and footer. A file without a footer is *torn*.

Every metadata value is stored as JSON text (MCAP metadata maps strings to strings), so numbers,
lists and nested sections keep their types; ``read_run`` decodes them.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding

from labrunner import __version__
from labrunner.errors import InvalidParameter, LabrunnerError, check_finite
from labrunner.logs import schema
from labrunner.logs.mcap_writer import BulkWriter

ROLES = ("input", "output", "controlled", "reference", "error", "estimate", "signal")
STATUSES = ("completed", "aborted", "no-motion", "failed")  # engine.RunResult.outcome["status"]
RESERVED_RECORDS = ("channels", "outcome")
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
    if isinstance(channels, Mapping) and channels and all(
        not isinstance(v, Mapping) for k, v in channels.items() if k != "units"
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


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store {type(value).__name__} in run metadata")


def encode_record(field: str, record: Mapping[str, Any]) -> dict[str, str]:
    """An MCAP metadata map: every value as JSON text (NaN and ±inf allowed)."""
    if not isinstance(record, Mapping):
        raise InvalidParameter(f"metadata.{field}", f"must be a mapping, got {type(record).__name__}")
    try:
        return {str(k): json.dumps(v, default=_jsonable) for k, v in record.items()}
    except TypeError as exc:
        raise InvalidParameter(f"metadata.{field}", str(exc)) from None


class RunLogWriter:
    """Stream one run into an MCAP file (real rigs), block by block; use as a context manager.

    ``metadata`` maps record names to mappings (``run``, ``config``, ...); ``channels`` names every
    signal a block will carry (see :func:`normalise_channels`). Each :meth:`write_block` call
    writes ⌈n / 1000⌉ block messages, so pass blocks of ~0.1 s rather than single samples. The file
    is flushed after the metadata and then at the first block after every ``flush_interval_s``
    (0: after every block); what was flushed survives a SIGKILL. Leaving the ``with`` block
    without :meth:`finish` (an exception, Ctrl-C) still closes the file cleanly, outcome ``failed``.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: Mapping[str, Mapping[str, Any]],
        fs: float,
        channels: Mapping[str, Any] | Sequence[str],
        attachments: Mapping[str, bytes] | None = None,
        flush_interval_s: float = 0.25,
        preview_hz: float = schema.PREVIEW_HZ,
    ) -> None:
        self.fs = check_finite("fs", fs)
        if self.fs <= 0:
            raise InvalidParameter("fs", f"must be > 0 Hz, got {fs}")
        preview_hz = check_finite("preview_hz", preview_hz)
        if not 0 < preview_hz <= schema.PREVIEW_MAX_HZ:
            raise InvalidParameter("preview_hz", f"must be in (0, {schema.PREVIEW_MAX_HZ:g}] Hz, got {preview_hz}")
        self.flush_interval_s = check_finite("flush_interval_s", flush_interval_s)
        if self.flush_interval_s < 0:
            raise InvalidParameter("flush_interval_s", f"must be >= 0 s, got {flush_interval_s}")
        self.channels = normalise_channels(channels)
        self.names = list(self.channels)
        records = self._records(metadata)
        attached = {str(name): bytes(data) for name, data in (attachments or {}).items()}
        self.decimation = max(1, math.ceil(self.fs / preview_hz - 1e-9))
        self.n_samples = 0
        self._prefixes = schema.signal_prefixes(self.names)
        self._sequence = 0
        self._finished = False
        self._file = open(path, "wb")  # noqa: SIM115 - closed in finish()
        self._mcap = BulkWriter(self._file)
        self._mcap.start(library=f"labrunner/{__version__}")
        for name, record in records.items():
            self._mcap.add_metadata(name, record)
        for name, data in attached.items():
            media = _MEDIA_TYPES.get(Path(name).suffix, "application/octet-stream")
            self._mcap.add_attachment(name, media, data)
        block_schema = self._mcap.add_schema(schema.BLOCK_SCHEMA_NAME, SchemaEncoding.Protobuf, schema.BLOCK_SCHEMA)
        self._block_channel = self._mcap.add_channel(schema.BLOCK_TOPIC, MessageEncoding.Protobuf, block_schema)
        preview_schema = self._mcap.add_schema(
            schema.PREVIEW_SCHEMA_NAME, SchemaEncoding.Protobuf, schema.preview_schema(self.names)
        )
        self._preview_channel = self._mcap.add_channel(
            schema.PREVIEW_TOPIC, MessageEncoding.Protobuf, preview_schema,
            {"decimation": str(self.decimation), "rate_hz": repr(self.fs / self.decimation)},
        )
        self._mcap.flush()
        self._last_flush = time.monotonic()

    def _records(self, metadata: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, str]]:
        if not isinstance(metadata, Mapping):
            raise InvalidParameter("metadata", f"must map record names to mappings, got {type(metadata).__name__}")
        reserved = sorted(set(metadata) & set(RESERVED_RECORDS))
        if reserved:
            raise InvalidParameter("metadata", f"record names {reserved} are written by the logger")
        run = metadata.get("run", {})
        if not isinstance(run, Mapping):
            raise InvalidParameter("metadata.run", f"must be a mapping, got {type(run).__name__}")
        run = {**run, "fs": self.fs}
        run.setdefault("labrunner_version", __version__)
        records = {"run": encode_record("run", run)}
        records.update({name: encode_record(name, rec) for name, rec in metadata.items() if name != "run"})
        records["channels"] = encode_record("channels", self.channels)
        return records

    def write_block(self, first_index: int, block: Mapping[str, np.ndarray]) -> None:
        """Append samples ``first_index .. first_index + n - 1`` of every signal (n ≥ 0)."""
        if self._finished:
            raise LabrunnerError("run log already finished")
        if set(block) != set(self.names):
            missing, extra = sorted(set(self.names) - set(block)), sorted(set(block) - set(self.names))
            raise InvalidParameter("block", f"signals must match the channels; missing {missing}, unknown {extra}")
        columns = [np.asarray(block[name], dtype=np.float64) for name in self.names]
        n = columns[0].shape[0] if columns[0].ndim == 1 else -1
        if any(c.ndim != 1 or c.shape[0] != n for c in columns):
            shapes = {name: c.shape for name, c in zip(self.names, columns)}
            raise InvalidParameter("block", f"signals must be 1-D arrays of one length, got {shapes}")
        first_index = int(first_index)
        if first_index < self.n_samples:
            raise InvalidParameter("first_index", f"must be >= {self.n_samples} (samples already written), got {first_index}")
        for start in range(0, n, schema.BLOCK_SAMPLES):
            k = first_index + start
            parts = schema.block_parts(k, self.fs, self._prefixes, [c[start : start + schema.BLOCK_SAMPLES] for c in columns])
            self._mcap.add_message(self._block_channel, self._log_time(k), self._sequence, parts)
            self._sequence += 1
        keep = np.arange((-first_index) % self.decimation, n, self.decimation)
        if keep.size:
            k = first_index + keep
            rows = schema.encode_preview(k / self.fs, [c[keep] for c in columns])
            sequences = np.arange(self._sequence, self._sequence + k.size)
            self._mcap.add_messages(self._preview_channel, self._log_time(k), sequences, rows)
            self._sequence += k.size
        self.n_samples = max(self.n_samples, first_index + n)
        if time.monotonic() - self._last_flush >= self.flush_interval_s:
            self._mcap.flush()
            self._last_flush = time.monotonic()

    def _log_time(self, k: int | np.ndarray) -> int | np.ndarray:
        """Log time [ns since the run's first sample] of sample(s) ``k``: round(k · 10⁹ / f_s)."""
        return round(k * 1e9 / self.fs) if isinstance(k, int) else np.rint(k * 1e9 / self.fs).astype(np.uint64)

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
            self._mcap.flush()  # the last chunk goes before the outcome
            self._mcap.add_metadata("outcome", record)
            self._mcap.finish()
        finally:
            self._file.close()

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
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
    fs: float,
    signals: Mapping[str, np.ndarray],
    outcome: Mapping[str, Any],
    attachments: Mapping[str, bytes] | None = None,
    channels: Mapping[str, Any] | Sequence[str] | None = None,
    preview_hz: float = schema.PREVIEW_HZ,
) -> None:
    """Write a finished run (all signals of one length K, sample k at k / fs) to ``path``."""
    described = normalise_channels(channels, list(signals))
    with RunLogWriter(
        path, metadata=metadata, fs=fs, channels=described, attachments=attachments, preview_hz=preview_hz
    ) as writer:
        writer.write_block(0, signals)
        writer.finish(outcome)
