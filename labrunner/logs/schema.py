"""Protobuf schemas of a run log and their wire encoding.

A run's signals are stored once, as ``/run/samples`` — message ``labrunner.logs.Sample``, one
message per sample at the full rate, so that Foxglove (or any protobuf-aware MCAP tool) plots
``/run/samples.<field>`` as a time series at every rate, the plate's 942 rad/s mode included. Its
type is built per run from the signal names and units, field j + 1 holding signal j of the
``channels`` record::

    message Sample { double <field_1> = 1; float <field_2> = 2; ... }

A field is a ``double`` (float64) unless its signal was given as float32 — a device's samples
(which are float32 on the device, so stored exactly), or every signal of a campaign whose
``[logging] precision`` is ``float32`` (rounded, by choice) — then it is a ``float``. Readers take
each field's type from the file's schema (:func:`float32_fields`); values come back as float64.

A field is named ``<signal>__<unit>`` (:func:`sample_field`): the signal's name, two underscores
and its SI unit spelt as an identifier (``/`` → ``_per_``, ``²`` → ``2``, ``·`` → ``_``), e.g.
``omega__rad_per_s``, ``h1__m``, ``i1__A``; a signal without unit keeps its bare name. So a plot's
legend names the unit, and the channel's metadata repeats it exactly (``unit.<field>`` = ``rad/s``).
Time is implicit: a message's MCAP ``sequence`` is its sample index k and its ``log_time`` the
wall-clock time of the sample (the run's start + k / f_s, ns since 1970).

``/run/blocks`` — message ``labrunner.logs.SignalBlock`` of packed float64 per signal, one message
per ≈ 1000 samples (:data:`BLOCK_SAMPLES`), sample k at k / f_s — is written only when the
campaign's ``[logging] samples_hz`` thins ``/run/samples``: then it is the lossless record. (Logs of
format ``labrunner-2`` hold both topics at the full rate, and their samples a ``t__s`` field; the
reader uses their blocks.)::

    message Signal      { string name = 1; repeated double values = 2 [packed = true]; }
    message SignalBlock { uint64 first_index = 1; double t0 = 2; double fs = 3;
                          repeated Signal signals = 4; }

Both schemas are stored in the file as serialised ``FileDescriptorSet`` (MCAP schema encoding
``protobuf``), built here from ``FileDescriptorProto`` objects, so no ``protoc`` step exists and
any protobuf-aware MCAP tool decodes the messages. The hot paths (writing and reading samples and
blocks) encode the wire format directly with numpy — a packed double field is the little-endian
float64 array itself, a sample a fixed-size row of tags and doubles — which is ~50× faster than
filling message objects; ``tests/test_logs.py`` and ``tests/test_logs_mcap.py`` check the bytes
against the generated message classes.
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
SAMPLES_TOPIC = "/run/samples"
BLOCK_SCHEMA_NAME = "labrunner.logs.SignalBlock"
SAMPLES_SCHEMA_NAME = "labrunner.logs.Sample"
BLOCK_SAMPLES = 1000  # samples per block message
_UNIT_SPELLING = (
    ("/", "_per_"),
    ("²", "2"),
    ("³", "3"),
    ("·", "_"),
    ("*", "_"),
    (" ", "_"),
    ("°", "deg"),
    ("µ", "u"),
    ("Ω", "Ohm"),
    ("%", "percent"),
    ("^", ""),
    ("(", ""),
    (")", ""),
    ("-", "_"),
)

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
        name="signals",
        number=4,
        type=_F.TYPE_MESSAGE,
        label=_F.LABEL_REPEATED,
        type_name=".labrunner.logs.Signal",
    )
    return fdp


Layout = tuple[bool, ...]  # per field of a Sample, in order: True where it is a float32 ``float``


def _samples_file(fields: Sequence[str], layout: Layout) -> descriptor_pb2.FileDescriptorProto:
    fdp = descriptor_pb2.FileDescriptorProto(
        name="labrunner/logs/sample.proto", package="labrunner.logs", syntax="proto3"
    )
    msg = fdp.message_type.add(name="Sample")
    for number, (name, single) in enumerate(zip(fields, layout, strict=True), start=1):
        kind = _F.TYPE_FLOAT if single else _F.TYPE_DOUBLE
        msg.field.add(name=name, number=number, type=kind, label=_F.LABEL_OPTIONAL)
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


def sample_field(name: str, unit: str) -> str:
    """The per-sample message's field of signal ``name`` in ``unit``: ``<name>__<unit spelt as an
    identifier>`` (``omega``, ``rad/s`` → ``omega__rad_per_s``), or ``name`` without a unit."""
    spelt = str(unit or "")
    for old, new in _UNIT_SPELLING:
        spelt = spelt.replace(old, new)
    spelt = re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9_]", "", spelt)).strip("_")
    return f"{name}__{spelt}" if spelt else name


def sample_fields(names: Sequence[str], units: Sequence[str]) -> list[str]:
    """Fields of the per-sample message for signals ``names`` in ``units`` (all distinct)."""
    check_signal_names(names)
    fields = [sample_field(n, u) for n, u in zip(names, units, strict=True)]
    if len(set(fields)) != len(fields):
        raise InvalidParameter("signals", f"names and units give clashing per-sample fields: {fields}")
    return fields


def samples_schema(fields: Sequence[str], layout: Layout | None = None) -> bytes:
    """Serialised ``FileDescriptorSet`` of this run's ``Sample`` message (``fields`` from
    :func:`sample_fields`; ``layout``: which are float32, default none)."""
    layout = (False,) * len(fields) if layout is None else tuple(layout)
    return descriptor_pb2.FileDescriptorSet(file=[_samples_file(fields, layout)]).SerializeToString()


def float32_fields(schema_data: bytes, n_fields: int) -> Layout:
    """The :data:`Layout` of the first ``n_fields`` fields of a stored ``Sample`` schema (field
    number j + 1 → entry j): True where the field is a protobuf ``float``. A schema that does not
    parse, or a field it lacks, counts as ``double`` (the layout labrunner-3 logs always had)."""
    try:
        files = descriptor_pb2.FileDescriptorSet.FromString(schema_data).file
    except Exception:  # noqa: BLE001 - another tool's or a damaged schema: the default layout
        return (False,) * n_fields
    kinds = {
        f.number: f.type
        for fdp in files
        for msg in fdp.message_type
        if f"{fdp.package}.{msg.name}" == SAMPLES_SCHEMA_NAME
        for f in msg.field
    }
    return tuple(kinds.get(j + 1) == _F.TYPE_FLOAT for j in range(n_fields))


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


def block_parts(
    first_index: int, fs: float, prefixes: Sequence[bytes], columns: Sequence[np.ndarray]
) -> list[bytes | np.ndarray]:
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


@functools.lru_cache(maxsize=64)
def sample_dtype(layout: Layout) -> np.dtype:
    """Wire layout of one ``Sample`` whose fields are float32 where ``layout`` says so, float64
    elsewhere: every field its tag (a varint of 1–2 bytes, held as a little-endian u1 or u2) and
    its little-endian value (zeros included), so that all messages have one size; fields ``s0``,
    ``s1``, ... with tags ``k_s0``, ``k_s1``, ..."""
    items = []
    for number, single in enumerate(layout, start=1):
        size = len(varint((number << 3) | 5))
        if size > 2:
            raise InvalidParameter("signals", f"at most 2047 signals fit the per-sample message, got {len(layout)}")
        items += [(f"k_s{number - 1}", f"<u{size}"), (f"s{number - 1}", "<f4" if single else "<f8")]
    return np.dtype(items)


@functools.lru_cache(maxsize=64)
def sample_tags(layout: Layout) -> np.ndarray:
    """One :func:`sample_dtype` row with the tags set (wire type 5, 32-bit, for a float32 field;
    1, 64-bit, for a double) and the values zero: the template that
    :func:`labrunner.logs.mcap_writer.message_array` broadcasts (read-only: it is shared)."""
    row = np.zeros(1, dtype=sample_dtype(layout))
    for number, single in enumerate(layout, start=1):
        row[f"k_s{number - 1}"] = int.from_bytes(varint((number << 3) | (5 if single else 1)), "little")
    row.flags.writeable = False
    return row


def fill_samples(rows: np.ndarray, columns: Sequence[np.ndarray]) -> None:
    """Write the values of ``Sample`` messages into ``rows`` (of :func:`sample_dtype`, tags from
    :func:`sample_tags`), row k from ``columns[j][k]`` (rounded to float32 in a float32 field,
    ±inf beyond its range)."""
    with np.errstate(over="ignore"):
        for j, values in enumerate(columns):
            rows[f"s{j}"] = values


def encode_samples(columns: Sequence[np.ndarray], layout: Layout | None = None) -> np.ndarray:
    """Wire bytes of one ``Sample`` per sample of ``columns`` (equal-length arrays, one per signal;
    ``layout`` default all float64): a (n, message size) uint8 array, row k the message of sample k
    (vectorised)."""
    n = len(columns[0])
    rows = np.repeat(sample_tags((False,) * len(columns) if layout is None else tuple(layout)), n)
    fill_samples(rows, columns)
    return rows.view(np.uint8).reshape(n, rows.dtype.itemsize)


_FLOAT = struct.Struct("<f")


def decode_samples(payloads: Sequence[bytes | memoryview], layout: Layout) -> np.ndarray:
    """(len(layout), len(payloads)) float64 of ``Sample`` messages: field j + 1 is row j; a field
    a message leaves out is NaN (proto3 would read 0.0, but labrunner writes every field), unknown
    fields are skipped; a 64-bit field is read as a double, a 32-bit one as a float, whatever
    ``layout`` says. The layout :func:`encode_samples` writes is read in one numpy view."""
    n_signals = len(layout)
    out = np.full((n_signals, len(payloads)), np.nan)
    template = sample_tags(layout)
    size = template.dtype.itemsize
    if payloads and all(len(p) == size for p in payloads):
        rows = np.frombuffer(b"".join(payloads), dtype=template.dtype)
        tags = [f"k_s{j}" for j in range(n_signals)]
        if all((rows[t] == template[t][0]).all() for t in tags):
            for j in range(n_signals):
                out[j] = rows[f"s{j}"]
            return out
    for i, payload in enumerate(payloads):  # any other valid encoding: field by field
        for number, wire, start, _ in _fields(payload, 0, len(payload)):
            if 1 <= number <= n_signals and wire in (1, 5):
                out[number - 1, i] = (_DOUBLE if wire == 1 else _FLOAT).unpack_from(payload, start)[0]
    return out
