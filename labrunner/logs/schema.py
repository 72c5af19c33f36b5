"""Protobuf schemas of a run log and their wire encoding.

Two topics carry a run's signals (``t`` is implicit: sample k is at k / f_s):

``/run/blocks`` — message ``labrunner.logs.SignalBlock``, the lossless record, one message per
≈ 1000 samples (:data:`BLOCK_SAMPLES`)::

    message Signal      { string name = 1; repeated double values = 2 [packed = true]; }
    message SignalBlock { uint64 first_index = 1; double t0 = 2; double fs = 3;
                          repeated Signal signals = 4; }

``/run/preview`` — message ``labrunner.logs.RunSample``, one message per kept sample, thinned to
≤ 1 kHz (500 Hz by default), so that Foxglove plots ``/run/preview.<signal>`` as a time series.
Its type is built per run from the signal names::

    message RunSample { double t = 1; double <signal_1> = 2; double <signal_2> = 3; ... }

Both schemas are stored in the file as serialised ``FileDescriptorSet`` (MCAP schema encoding
``protobuf``), built here from ``FileDescriptorProto`` objects, so no ``protoc`` step exists and
any protobuf-aware MCAP tool decodes the messages. The hot paths (writing and reading blocks,
writing preview samples) encode the wire format directly with numpy — a packed double field is
the little-endian float64 array itself, a preview sample a fixed-size row of tags and doubles —
which is ~50× faster than filling message objects; ``tests/test_logs.py`` and
``tests/test_logs_mcap.py`` check the bytes against the generated message classes.
"""

from __future__ import annotations

import functools
import re
import struct
from collections.abc import Sequence

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from labrunner.errors import InvalidParameter

BLOCK_TOPIC = "/run/blocks"
PREVIEW_TOPIC = "/run/preview"
BLOCK_SCHEMA_NAME = "labrunner.logs.SignalBlock"
PREVIEW_SCHEMA_NAME = "labrunner.logs.RunSample"
BLOCK_SAMPLES = 1000  # samples per block message
PREVIEW_MAX_HZ = 1000.0  # highest rate of the per-sample preview channel [Hz]
# Default preview rate [Hz]: the preview repeats the blocks' data, so it is kept to what a plot of a
# run needs (a sample of ten signals is a 130-byte message, < 1 µs to encode and compress with
# the bulk writer); a run at f_s ≤ 500 Hz, such as the motor's at 200 Hz, is not thinned at all.
PREVIEW_HZ = 500.0

_F = descriptor_pb2.FieldDescriptorProto
_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_DOUBLE = struct.Struct("<d")


def _block_file() -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(
        name="labrunner/logs/signal_block.proto", package="labrunner.logs", syntax="proto3"
    )
    sig = fdp.message_type.add(name="Signal")
    sig.field.add(name="name", number=1, type=_F.TYPE_STRING, label=_F.LABEL_OPTIONAL)
    values = sig.field.add(name="values", number=2, type=_F.TYPE_DOUBLE, label=_F.LABEL_REPEATED)
    values.options.packed = True
    block = fdp.message_type.add(name="SignalBlock")
    block.field.add(name="first_index", number=1, type=_F.TYPE_UINT64, label=_F.LABEL_OPTIONAL)
    block.field.add(name="t0", number=2, type=_F.TYPE_DOUBLE, label=_F.LABEL_OPTIONAL)
    block.field.add(name="fs", number=3, type=_F.TYPE_DOUBLE, label=_F.LABEL_OPTIONAL)
    block.field.add(
        name="signals", number=4, type=_F.TYPE_MESSAGE, label=_F.LABEL_REPEATED,
        type_name=".labrunner.logs.Signal",
    )
    return fdp


def _preview_file(names: Sequence[str]) -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(
        name="labrunner/logs/run_sample.proto", package="labrunner.logs", syntax="proto3"
    )
    msg = fdp.message_type.add(name="RunSample")
    for number, name in enumerate(("t", *names), start=1):
        msg.field.add(name=name, number=number, type=_F.TYPE_DOUBLE, label=_F.LABEL_OPTIONAL)
    return fdp


def message_class(fdp: descriptor_pb2.FileDescriptorProto, full_name: str) -> type:
    """The generated message class for ``full_name`` in ``fdp`` (a private descriptor pool)."""
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(full_name))


_BLOCK_FILE = _block_file()
SignalBlock = message_class(_BLOCK_FILE, BLOCK_SCHEMA_NAME)  # validates the schema at import
BLOCK_SCHEMA = descriptor_pb2.FileDescriptorSet(file=[_BLOCK_FILE]).SerializeToString()


def check_signal_names(names: Sequence[str]) -> None:
    """Signal names become protobuf field names: identifiers, unique, and not ``t``."""
    if not names:
        raise InvalidParameter("signals", "need at least one signal")
    for name in names:
        if not isinstance(name, str) or not _IDENTIFIER.match(name):
            raise InvalidParameter(f"signals.{name}", "must be an identifier [A-Za-z_][A-Za-z0-9_]*")
        if name == "t":
            raise InvalidParameter("signals.t", "is reserved for time (sample k is at k / fs)")
    if len(set(names)) != len(names):
        raise InvalidParameter("signals", f"names must be unique, got {list(names)}")


def preview_schema(names: Sequence[str]) -> bytes:
    """Serialised ``FileDescriptorSet`` of this run's ``RunSample`` message."""
    check_signal_names(names)
    return descriptor_pb2.FileDescriptorSet(file=[_preview_file(names)]).SerializeToString()


def varint(n: int) -> bytes:
    """Protobuf base-128 varint of a non-negative integer."""
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _read_varint(buf: bytes | memoryview, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        if byte < 0x80:
            return value, pos
        shift += 7


def _fields(buf: bytes | memoryview, pos: int, end: int):
    """Yield ``(field_number, wire_type, value_or_start, stop)`` for each field in buf[pos:end]."""
    while pos < end:
        key, pos = _read_varint(buf, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _read_varint(buf, pos)
            yield number, wire, value, pos
        elif wire == 1:
            yield number, wire, pos, pos + 8
            pos += 8
        elif wire == 2:
            length, pos = _read_varint(buf, pos)
            yield number, wire, pos, pos + length
            pos += length
        elif wire == 5:
            yield number, wire, pos, pos + 4
            pos += 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
    if pos != end:
        raise ValueError("protobuf message overruns its length")


def signal_prefixes(names: Sequence[str]) -> list[bytes]:
    """Pre-encoded ``Signal.name`` fields (tag, length, UTF-8), one per signal."""
    return [b"\x0a" + varint(len(b)) + b for b in (n.encode() for n in names)]


def block_parts(first_index: int, fs: float, prefixes: Sequence[bytes], columns: Sequence[np.ndarray]) -> list[bytes | np.ndarray]:
    """Wire bytes of a ``SignalBlock`` as pieces to concatenate; ``columns`` are float64 arrays
    of equal length (``prefixes`` from :func:`signal_prefixes`).

    A packed double field is the little-endian float64 array itself, so the arrays are pieces as
    they are: the message is first assembled when its chunk is, without an intermediate copy.
    """
    parts: list[bytes | np.ndarray] = [
        b"\x08" + varint(first_index) + b"\x11" + _DOUBLE.pack(first_index / fs) + b"\x19" + _DOUBLE.pack(fs)
    ]
    for prefix, column in zip(prefixes, columns, strict=True):
        values = np.ascontiguousarray(column, dtype="<f8")
        parts += [_signal_header(prefix, values.nbytes), values]
    return parts


@functools.lru_cache(maxsize=256)
def _signal_header(prefix: bytes, nbytes: int) -> bytes:
    """``SignalBlock.signals`` tag and length, the ``Signal.name`` field, the ``values`` tag and
    length: what precedes ``nbytes`` of packed doubles (the same for every full block)."""
    values_len = varint(nbytes)
    return b"\x22" + varint(len(prefix) + 1 + len(values_len) + nbytes) + prefix + b"\x12" + values_len


def encode_block(first_index: int, fs: float, prefixes: Sequence[bytes], columns: Sequence[np.ndarray]) -> bytes:
    """Wire bytes of a ``SignalBlock`` (:func:`block_parts` joined)."""
    return b"".join(block_parts(first_index, fs, prefixes, columns))


def _doubles(buf: bytes | memoryview, wire: int, start: int, stop: int) -> np.ndarray:
    if wire == 1 or (wire == 2 and (stop - start) % 8 == 0):
        return np.frombuffer(buf, dtype="<f8", count=(stop - start) // 8, offset=start)
    raise ValueError(f"Signal.values has wire type {wire} and {stop - start} bytes: not doubles")


def _signal(buf: bytes | memoryview, start: int, stop: int) -> tuple[str, np.ndarray]:
    """``(name, values)`` of one ``Signal`` submessage in buf[start:stop]."""
    # fast path, the layout encode_block writes: name field, then one packed values field
    if buf[start] == 0x0A:
        n_len, pos = _read_varint(buf, start + 1)
        if pos + n_len < stop and buf[pos + n_len] == 0x12:
            v_len, v_pos = _read_varint(buf, pos + n_len + 1)
            if v_pos + v_len == stop and v_len % 8 == 0:
                return str(buf[pos : pos + n_len], "utf-8"), np.frombuffer(buf, "<f8", v_len // 8, v_pos)
    name, pieces = "", []
    for number, wire, s, e in _fields(buf, start, stop):
        if number == 1 and wire == 2:
            name = str(buf[s:e], "utf-8")
        elif number == 2:
            pieces.append(_doubles(buf, wire, s, e))
    return name, pieces[0] if len(pieces) == 1 else np.concatenate(pieces or [np.empty(0)])


def decode_block(buf: bytes | memoryview) -> tuple[int, float, dict[str, np.ndarray]]:
    """``(first_index, fs, {name: values})`` of a ``SignalBlock``; values are read-only views.

    Accepts any valid encoding (packed or not, fields in any order, unknown fields skipped).
    """
    first_index, fs, signals = 0, float("nan"), {}
    for number, wire, start, stop in _fields(buf, 0, len(buf)):
        if number == 1 and wire == 0:
            first_index = start
        elif number == 3 and wire == 1:
            fs = _DOUBLE.unpack_from(buf, start)[0]
        elif number == 4 and wire == 2 and stop > start:
            name, values = _signal(buf, start, stop)
            signals[name] = np.concatenate([signals[name], values]) if name in signals else values
    return first_index, fs, signals


def encode_preview(t: np.ndarray, columns: Sequence[np.ndarray]) -> np.ndarray:
    """Wire bytes of one ``RunSample`` per element of ``t``: a (len(t), 9 · (1 + len(columns)))
    uint8 array, row k the message of sample k (vectorised: every field is a 1-byte tag and a
    little-endian double, zeros included, so all records have one size)."""
    fields = [("t", t), *((f"s{j}", c) for j, c in enumerate(columns))]
    tags = [varint((number << 3) | 1) for number in range(1, len(fields) + 1)]
    dtype = np.dtype(
        [item for (key, _), tag in zip(fields, tags) for item in ((f"k_{key}", "u1", (len(tag),)), (key, "<f8"))]
    )
    records = np.empty(len(t), dtype=dtype)
    for (key, values), tag in zip(fields, tags):
        records[f"k_{key}"] = np.frombuffer(tag, dtype="u1")
        records[key] = values
    return records.view(np.uint8).reshape(len(t), dtype.itemsize)
