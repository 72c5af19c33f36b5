"""The run description a device-loop rig receives: one resolved campaign point, fixed header + TLV
records + CRC-32, every byte in docs/device-loop.md (pure, no I/O).

The description carries the point's sections as named parameter records (the firmware reads the
gains by name, the reference executor rebuilds the controller from them with the engine's own
factory) *and* everything a firmware would otherwise have to design: the differentiator's FIR
weights of every derivative order the law uses, the controller's discretised linear filters, the
input saturation, the reference as resolved
poly-5 segments (or steps, or a sine) or, where the rig file asks for it or a trajectory has no
compact form, as a sample table read by tick index, the safety limits with the |du/dt| estimator's weights and
the weights of derived outputs (the plate's air gaps), the watchdog, f_s, the tick count and the
seed. :func:`build` refuses at plan time what a description cannot carry, with a one-line
:class:`~labrunner.errors.InvalidParameter`.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from labrunner.control import factory
from labrunner.control.trajectories import Setpoints, Sine, Steps, Table, Trajectory
from labrunner.differentiators import design as design_rate
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigInfo
from labrunner.rigs.device import lawrecords
from labrunner.rigs.device.columns import column_count
from labrunner.safety import SafetyConfig

MAGIC = b"LRDL"
VERSION = 1
HEADER = struct.Struct("<4sHHIHH")  # magic, version, header bytes, body bytes, flags, record count
RECORD = struct.Struct("<HHI")  # type, flags (0), value bytes
RUN = struct.Struct("<ddIIdBBH")  # fs, duration, ticks, seed, watchdog, n_inputs, n_outputs, n_columns
FLAG_STREAM = 0x0001  # header flag: send the samples during the run

#: record types (docs/device-loop.md, "Run description")
R_RUN, R_KIND, R_PARAM, R_FIR, R_SATURATION, R_BOUNDS, R_RATE, R_MAX_DURATION, R_TRAJECTORY, R_DERIVED, R_FILTER = (
    range(1, 12)
)
#: point sections carried as parameter records, by id (``rig_safety``: the rig file's [safety])
SECTIONS = {"controller": 1, "differentiator": 2, "reference": 3, "safety": 4, "rig_safety": 5}
#: parameter value types
T_F64, T_I64, T_BOOL, T_STR, T_F64_LIST, T_F64_LISTS = range(1, 7)
#: FIR purposes: the controller's differentiator, the safety routine's |du/dt| estimator
FIR_CONTROLLER, FIR_RATE = 0, 1
#: bound kinds: inputs, measured outputs, derived outputs
B_INPUT, B_OUTPUT, B_DERIVED = range(3)
#: trajectory types and their parameter arrays (Trajectory._params)
TRAJECTORIES = {Setpoints: 1, Steps: 2, Sine: 3}
#: the sample-table trajectory type: arrays (f_s,) and the rows (value, 3 derivatives) row-major
T_TABLE = 4
#: controller kinds device firmware runs → the highest derivative order of their differentiator
DEVICE_KINDS = {
    "mfc1": 1,
    "mfc1-ff": 1,
    "mfc2": 2,
    "plate-mfc": 2,
    "plate-mbc": None,
    "open-loop": None,
    "valve-ffc": None,
}


@dataclass(frozen=True)
class Description:
    """A decoded run description (``sections`` rebuild the point; the rest is what firmware runs on)."""

    fs: float
    duration: float
    ticks: int
    seed: int
    watchdog_s: float
    n_inputs: int
    n_outputs: int
    n_columns: int
    kind: str
    sections: dict[str, dict[str, object]]
    fir: dict[tuple[int, int], np.ndarray] = field(default_factory=dict)  # (purpose, order) → weights
    saturation: tuple[np.ndarray, np.ndarray] | None = None
    bounds: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    rate: tuple[float, float, float, float] | None = None  # max |du/dt|, α, β, ω_c
    max_duration: float = np.inf
    trajectories: list[tuple[int, list[np.ndarray]]] = field(default_factory=list)  # per output
    derived: np.ndarray | None = None  # (n_derived, n_outputs) weights
    stream: bool = False  # send the samples during the run
    filters: dict[str, np.ndarray] = field(default_factory=dict)  # name → (n + m, p + n) tick matrix
    law: dict[str, np.ndarray] = field(default_factory=dict)  # LAW records: name → (rows, columns)
    motion: tuple[int, int, float] | None = None  # MOTION: output index, rule, threshold
    sensor_table: np.ndarray | None = None  # SENSOR_TABLE (n, n_outputs): y from the host, no plant

    def point(self) -> dict[str, object]:
        """The campaign point these sections came from (what the engine's factory reads)."""
        return {k: dict(v) for k, v in self.sections.items() if k != "rig_safety"}


def _value(section: str, key: str, value: object) -> tuple[int, bytes]:
    """(type, bytes) of one parameter value; refuses what a record cannot carry."""
    where = f"{section}.{key}"
    if isinstance(value, (bool, np.bool_)):
        return T_BOOL, struct.pack("<B", bool(value))
    if isinstance(value, (int, np.integer)):
        return T_I64, struct.pack("<q", int(value))
    if isinstance(value, (float, np.floating)):
        return T_F64, struct.pack("<d", float(value))
    if isinstance(value, str):
        raw = value.encode("ascii", "replace")
        if len(raw) > 255 or not value.isascii():
            raise InvalidParameter(
                where, f"cannot be sent to a device-loop rig: needs an ASCII string of at most 255 bytes, got {value!r}"
            )
        return T_STR, struct.pack("<H", len(raw)) + raw
    if isinstance(value, (list, tuple)) and all(_is_number(v) for v in value):
        return T_F64_LIST, struct.pack("<I", len(value)) + np.asarray(value, "<f8").tobytes()
    if (
        isinstance(value, (list, tuple))
        and value
        and all(isinstance(v, (list, tuple)) and all(_is_number(x) for x in v) for v in value)
    ):
        lengths = np.asarray([len(v) for v in value], "<u4")
        flat = np.asarray([x for v in value for x in v], "<f8")
        return T_F64_LISTS, struct.pack("<H", len(value)) + lengths.tobytes() + flat.tobytes()
    raise InvalidParameter(
        where,
        f"cannot be sent to a device-loop rig: needs a number, bool, string or (nested) list of numbers, got {value!r}",
    )


def _is_number(v: object) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _record(kind: int, value: bytes) -> bytes:
    return RECORD.pack(kind, 0, len(value)) + value


def _f64(values: object) -> bytes:
    return np.asarray(values, "<f8").tobytes()


def build(
    point: Mapping[str, object],
    rig_info: RigInfo,
    *,
    fs: float,
    duration: float,
    seed: int,
    rig_safety: Mapping[str, object] | None = None,
    watchdog_s: float = 0.5,
    reference_table: bool = False,
    sensor_table: np.ndarray | None = None,
) -> bytes:
    """The encoded description of one resolved ``point``; raises InvalidParameter for what the
    device loop cannot run (unknown kind, per-run rig parameters, values without an encoding).
    ``reference_table`` sends every trajectory as its sample table (firmware without the compact
    trajectory types); ``sensor_table`` (n, n_outputs) has the device read y[k] from it instead
    of its sensors (conformance runs). The STREAM flag is clear: :func:`with_stream` sets it where the link has
    room for the samples."""
    kind = str(dict(point.get("controller") or {}).get("kind"))
    if kind not in DEVICE_KINDS:
        raise InvalidParameter(
            "controller.kind", f"{kind!r} cannot run on a device-loop rig (device kinds: {', '.join(DEVICE_KINDS)})"
        )
    if point.get("rig_parameters"):
        raise InvalidParameter("rig_parameters", "a device-loop rig has no per-run rig parameters; remove the section")
    controller, reference = factory.build([point], rig_info, fs)  # every check the engine runs
    config = SafetyConfig.from_sections(rig_info, rig_safety or {}, dict(point.get("safety") or {}))
    ticks = int(round(duration * fs))
    if not 0 < ticks < 2**32:
        raise InvalidParameter("campaign.duration", f"needs 1..2³²−1 ticks at {fs:g} Hz, got {duration!r} s")
    records = [
        _record(
            R_RUN,
            RUN.pack(
                float(fs),
                float(duration),
                ticks,
                int(seed) % 2**32,
                float(watchdog_s),
                len(rig_info.inputs),
                len(rig_info.outputs),
                column_count(rig_info, controller),
            ),
        )
    ]
    records.append(_record(R_KIND, kind.encode("ascii")))
    sections = {name: dict(point.get(name) or {}) for name in SECTIONS if name != "rig_safety"}
    sections["rig_safety"] = dict(rig_safety or {})
    for name, section in sections.items():
        for key, value in section.items():
            if name in ("safety", "rig_safety") and isinstance(value, Mapping):  # bounds tables: one record per signal
                for signal, pair in value.items():
                    records.append(_param(name, f"{key}.{signal}", pair))
            else:
                records.append(_param(name, key, value))
    order = DEVICE_KINDS[kind]
    if order is not None and point.get("differentiator"):
        design = factory.differentiators([point], fs, order)[0]
        records += [
            _record(R_FIR, struct.pack("<BBI", FIR_CONTROLLER, n, design.weights(n).size) + _f64(design.weights(n)))
            for n in range(order + 1)
        ]
    records.append(
        _record(
            R_SATURATION, struct.pack("<B", controller.n_inputs) + _f64(controller.u_min[0]) + _f64(controller.u_max[0])
        )
    )
    for code, signals, key in (
        (B_INPUT, rig_info.inputs, "input_bounds"),
        (B_OUTPUT, rig_info.outputs, "output_bounds"),
        (B_DERIVED, rig_info.derived, "output_bounds"),
    ):
        if signals:
            limits = getattr(config, key)
            lo = [limits.get(s.name, (-np.inf, np.inf))[0] for s in signals]
            hi = [limits.get(s.name, (-np.inf, np.inf))[1] for s in signals]
            records.append(_record(R_BOUNDS, struct.pack("<BB", code, len(signals)) + _f64(lo) + _f64(hi)))
    if rig_info.derived:
        weights = np.array([d.weights for d in rig_info.derived], dtype=float)
        records.append(_record(R_DERIVED, struct.pack("<BB", *weights.shape) + _f64(weights)))
    if config.max_du_dt is not None:
        records.append(
            _record(R_RATE, _f64([config.max_du_dt, config.du_dt_alpha, config.du_dt_beta, config.du_dt_omega_c]))
        )
        w = design_rate(alpha=config.du_dt_alpha, beta=config.du_dt_beta, omega_c=config.du_dt_omega_c, fs=fs).weights(
            1
        )
        records.append(_record(R_FIR, struct.pack("<BBI", FIR_RATE, 1, w.size) + _f64(w)))
    records.append(_record(R_MAX_DURATION, _f64([np.inf if config.max_duration is None else config.max_duration])))
    for j, trajectory in enumerate(reference.trajectories[0]):
        code, arrays = trajectory_record(trajectory, fs, ticks, reference_table)
        body = struct.pack("<BBB", j, code, len(arrays)) + b"".join(struct.pack("<I", a.size) + _f64(a) for a in arrays)
        records.append(_record(R_TRAJECTORY, body))
    for name, f in _streaming_filters(controller).items():
        raw = name.encode("ascii")
        records.append(_record(R_FILTER, struct.pack("<BHBB", len(raw), f.n, f.m, f.p) + raw + _f64(f._M[0])))
    records += [
        _record(lawrecords.R_LAW, lawrecords.encode(lawrecords.R_LAW, c))
        for c in sorted(lawrecords.law_constants(controller).items())
    ]
    records.append(
        _record(lawrecords.R_MOTION, lawrecords.encode(lawrecords.R_MOTION, lawrecords.motion_rule(config, rig_info)))
    )
    if sensor_table is not None:
        table = np.asarray(sensor_table, float)
        if table.ndim != 2 or table.shape[1] != len(rig_info.outputs) or not 0 < len(table) < 2**32:
            raise InvalidParameter("sensor_table", f"needs (rows ≥ 1, {len(rig_info.outputs)}), got {table.shape}")
        records.append(_record(lawrecords.R_SENSOR_TABLE, lawrecords.encode(lawrecords.R_SENSOR_TABLE, table)))
    body = b"".join(records)
    head = HEADER.pack(MAGIC, VERSION, HEADER.size, len(body), 0, len(records))
    return head + body + struct.pack("<I", zlib.crc32(head + body))


def with_stream(data: bytes, stream: bool) -> bytes:
    """The same description with its STREAM flag set or cleared (and its CRC-32 renewed)."""
    head = bytearray(data[:-4])
    flags = int.from_bytes(head[12:14], "little")
    head[12:14] = ((flags | FLAG_STREAM) if stream else (flags & ~FLAG_STREAM)).to_bytes(2, "little")
    return bytes(head) + struct.pack("<I", zlib.crc32(head))


def _param(section: str, key: str, value: object) -> bytes:
    name = key.encode("ascii")
    if len(name) > 255 or not key.isascii():
        raise InvalidParameter(
            f"{section}.{key}", "cannot be sent to a device-loop rig: keys are ASCII of at most 255 bytes"
        )
    code, raw = _value(section, key, value)
    return _record(R_PARAM, struct.pack("<BBB", SECTIONS[section], code, len(name)) + name + raw)


class DescriptionError(ValueError):
    """A description the device refuses: bad magic, version, length or CRC, or a malformed record."""


def decode(data: bytes) -> Description:
    """Parse and check an encoded description (raises :class:`DescriptionError`)."""
    if len(data) < HEADER.size + 4:
        raise DescriptionError(f"description of {len(data)} bytes is shorter than its header and CRC")
    magic, version, head_len, body_len, flags, n_records = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise DescriptionError(f"bad magic {magic!r}")
    if version != VERSION:
        raise DescriptionError(f"description version {version}; this device speaks {VERSION}")
    if head_len + body_len + 4 != len(data):
        raise DescriptionError(f"description of {len(data)} bytes, its header says {head_len + body_len + 4}")
    (crc,) = struct.unpack_from("<I", data, len(data) - 4)
    if zlib.crc32(data[:-4]) != crc:
        raise DescriptionError("description CRC-32 mismatch")
    run: tuple | None = None
    out: dict[str, object] = {
        "sections": {name: {} for name in SECTIONS},
        "fir": {},
        "bounds": {},
        "trajectories": [],
        "filters": {},
        "stream": bool(flags & FLAG_STREAM),
    }
    names = {v: k for k, v in SECTIONS.items()}
    pos, end = head_len, len(data) - 4
    try:
        for _ in range(n_records):
            kind, _, size = RECORD.unpack_from(data, pos)
            value = data[pos + RECORD.size : pos + RECORD.size + size]
            pos += RECORD.size + size
            if len(value) != size or pos > end:
                raise DescriptionError("record runs past the end of the description")
            if kind == R_RUN:
                run = RUN.unpack(value)
            elif kind == R_KIND:
                out["kind"] = value.decode("ascii")
            elif kind == R_PARAM:
                section, code, n = struct.unpack_from("<BBB", value)
                key = value[3 : 3 + n].decode("ascii")
                _set(out["sections"][names[section]], key, _unvalue(code, value[3 + n :]))  # type: ignore[index]
            elif kind == R_FIR:
                purpose, order, n = struct.unpack_from("<BBI", value)
                out["fir"][(purpose, order)] = np.frombuffer(value, "<f8", n, 6).copy()  # type: ignore[index]
            elif kind == R_SATURATION:
                n = value[0]
                a = np.frombuffer(value, "<f8", 2 * n, 1)
                out["saturation"] = (a[:n].copy(), a[n:].copy())
            elif kind == R_BOUNDS:
                code, n = value[0], value[1]
                a = np.frombuffer(value, "<f8", 2 * n, 2)
                out["bounds"][code] = (a[:n].copy(), a[n:].copy())  # type: ignore[index]
            elif kind == R_DERIVED:
                rows, cols = value[0], value[1]
                out["derived"] = np.frombuffer(value, "<f8", rows * cols, 2).reshape(rows, cols).copy()
            elif kind == R_RATE:
                out["rate"] = tuple(float(x) for x in np.frombuffer(value, "<f8", 4))
            elif kind == R_MAX_DURATION:
                out["max_duration"] = float(np.frombuffer(value, "<f8", 1)[0])
            elif kind == R_TRAJECTORY:
                _, code, count = struct.unpack_from("<BBB", value)
                arrays, at = [], 3
                for _ in range(count):
                    (n,) = struct.unpack_from("<I", value, at)
                    arrays.append(np.frombuffer(value, "<f8", n, at + 4).copy())
                    at += 4 + 8 * n
                out["trajectories"].append((code, arrays))  # type: ignore[union-attr]
            elif kind == R_FILTER:
                n_name, n, m, p = struct.unpack_from("<BHBB", value)
                name = value[5 : 5 + n_name].decode("ascii")
                matrix = np.frombuffer(value, "<f8", (n + m) * (p + n), 5 + n_name).reshape(n + m, p + n)
                out["filters"][name] = matrix.copy()  # type: ignore[index]
            elif kind in (lawrecords.R_SENSOR_TABLE, lawrecords.R_MOTION, lawrecords.R_LAW):
                lawrecords.decode_into(kind, value, out)
            else:
                raise DescriptionError(f"unknown record type {kind}")
    except (struct.error, ValueError, KeyError, IndexError) as exc:
        if isinstance(exc, DescriptionError):
            raise
        raise DescriptionError(f"malformed record: {exc}") from None
    if run is None or "kind" not in out:
        raise DescriptionError("description without its RUN or KIND record")
    fs, duration, ticks, seed, watchdog, n_in, n_out, n_cols = run
    return Description(fs, duration, ticks, seed, watchdog, n_in, n_out, n_cols, **out)  # type: ignore[arg-type]


def _unvalue(code: int, raw: bytes) -> object:
    if code == T_F64:
        return struct.unpack_from("<d", raw)[0]
    if code == T_I64:
        return struct.unpack_from("<q", raw)[0]
    if code == T_BOOL:
        return bool(raw[0])
    if code == T_STR:
        (n,) = struct.unpack_from("<H", raw)
        return raw[2 : 2 + n].decode("ascii")
    if code == T_F64_LIST:
        (n,) = struct.unpack_from("<I", raw)
        return np.frombuffer(raw, "<f8", n, 4).tolist()
    if code == T_F64_LISTS:
        (rows,) = struct.unpack_from("<H", raw)
        lengths = np.frombuffer(raw, "<u4", rows, 2)
        flat = np.frombuffer(raw, "<f8", int(lengths.sum()), 2 + 4 * rows).tolist()
        bounds = np.concatenate([[0], np.cumsum(lengths)])
        return [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    raise DescriptionError(f"unknown parameter type {code}")


def _set(section: dict[str, object], key: str, value: object) -> None:
    """Store ``key``; a dotted key (``output_bounds.h1``) goes into its table."""
    table, dot, signal = key.partition(".")
    if dot:
        section.setdefault(table, {})[signal] = value  # type: ignore[union-attr]
    else:
        section[key] = value


def rig_safety(description: Description) -> dict[str, object]:
    """The rig file's [safety] section the description carries."""
    return dict(description.sections.get("rig_safety", {}))


def trajectory_record(
    trajectory: Trajectory, fs: float, ticks: int, table: bool = False
) -> tuple[int, list[np.ndarray]]:
    """(type code, parameter arrays) of one output's trajectory as :func:`build` sends it: its
    compact form, or with ``table`` (or no compact form) its samples at the run's ticks."""
    code = None if table else TRAJECTORIES.get(type(trajectory))
    if code is None:
        sampled = Table.sample(trajectory, fs, ticks)
        return T_TABLE, [np.array([sampled.fs]), sampled.rows.ravel()]
    return code, [np.atleast_1d(np.asarray(a, float)) for a in trajectory._params()]


def executed_trajectories(description: Description, reference_rows: Sequence[Trajectory]) -> list[Trajectory]:
    """What a device runs per output: a sent table as a :class:`Table`, else the point's trajectory."""
    return [
        Table(float(arrays[0][0]), arrays[1].reshape(-1, 4)) if code == T_TABLE else trajectory
        for (code, arrays), trajectory in zip(description.trajectories, reference_rows)
    ]


def _streaming_filters(controller: object) -> dict[str, object]:
    from labrunner.control.plate_filters import StreamingSS

    return {name: obj for name, obj in sorted(vars(controller).items()) if isinstance(obj, StreamingSS)}


def filter_matrices(controller: object) -> dict[str, np.ndarray]:
    """The controller's streaming linear filters (the plate's notch, the MBC's observer chain) as
    their per-tick matrices M of run 0: [out[k], x[k+1]] = [x[k], w[k]] · M, so firmware runs
    them without designing them (Tustin, pole placement: labrunner/control/plate_filters.py)."""
    return {name: np.array(f._M[0]) for name, f in _streaming_filters(controller).items()}
