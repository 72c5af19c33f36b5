"""The one Rig interface every rig speaks: simulated twins and real rigs over CAN or serial.

A rig advances a *batch* of B independent runs in lockstep (B = 1 for a real rig). Arrays have a
leading batch axis: inputs ``u`` are ``(B, n_inputs)``, measurements ``y`` are ``(B, n_outputs)``.

The public methods are template methods (python-can's ``BusABC`` pattern): the base class does
what every rig must do the same way — input clipping to the rig's limits, the safe state of
tripped runs, actuator and sensor faults, the sample count, rejecting unknown per-run overrides —
and a backend implements only ``_reset`` and ``_step``. The class methods of :class:`Rig` are
the contract the registry and the rig-file loader use (:mod:`labrunner.rigs.kinds` checks a
class against it when it is registered); ``docs/writing-a-rig.md`` walks through a new rig.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from labrunner._ufunc import clip
from labrunner.errors import InvalidParameter
from labrunner.rigs.schema import Schema, validate_section


@dataclass(frozen=True)
class Signal:
    """One input or output channel: name, SI unit and its physical limits [lo, hi]."""

    name: str
    unit: str
    lo: float = -np.inf
    hi: float = np.inf
    resolution: float = 0.0  # smallest detectable change of a measurement (0: continuous)


@dataclass(frozen=True)
class Derived:
    """A signal computed from the rig's outputs, Σ_j weights[j]·y_j, that safety bounds may name
    like an output (the plate's magnet air gaps from its sensors, paper 2 eq. (4))."""

    name: str
    unit: str
    weights: tuple[float, ...]  # one per output


@dataclass(frozen=True)
class Faults:
    """Faults of paper 2 Sec. 4.4, active from ``t_start`` [s] on.

    Applied input: ``u_applied = (1 + actuator_gain) * u + actuator_offset``;
    measurement: ``y_measured = y + sensor_step``. Each entry is per channel (broadcast).
    """

    t_start: float = np.inf
    actuator_offset: tuple[float, ...] = (0.0,)
    actuator_gain: tuple[float, ...] = (0.0,)
    sensor_step: tuple[float, ...] = (0.0,)

    @property
    def any(self) -> bool:
        return np.isfinite(self.t_start) and (
            any(self.actuator_offset) or any(self.actuator_gain) or any(self.sensor_step)
        )


@dataclass(frozen=True)
class RigInfo:
    """What a rig is: its signals, allowed sampling rates, safe input and nominal constants.

    ``constants`` are nominal model values a campaign may use in ``[derived]`` expressions and the
    analysis uses for stability overlays (e.g. the DC motor's ``a`` [1/s] and ``b`` [rad/(V s²)]).
    """

    name: str
    kind: str
    inputs: tuple[Signal, ...]
    outputs: tuple[Signal, ...]
    fs_range: tuple[float, float]  # allowed sampling rates [Hz], inclusive
    fs_default: float
    safe_input: tuple[float, ...]  # the input a tripped run is held at (one per input)
    constants: Mapping[str, float] = field(default_factory=dict)
    simulated: bool = True
    description: str = ""
    derived: tuple[Derived, ...] = ()

    @property
    def input_lo(self) -> np.ndarray:
        return np.array([s.lo for s in self.inputs])

    @property
    def input_hi(self) -> np.ndarray:
        return np.array([s.hi for s in self.inputs])

    def check_fs(self, fs: float, field_name: str = "fs") -> float:
        lo, hi = self.fs_range
        if not (np.isfinite(fs) and lo <= fs <= hi):
            raise InvalidParameter(field_name, f"must be in [{lo:g}, {hi:g}] Hz for rig {self.name!r}, got {fs!r}")
        return float(fs)


@dataclass(frozen=True)
class RigConfig:
    """A validated rig file. ``parameters``/``noise`` have every key of the kind's schema filled in.

    ``limits`` narrows the rig's signal limits and sampling rates (``{signal: (lo, hi)}``, plus
    ``fs: (lo, hi)`` and ``fs_default``); ``safety`` is the ``[safety]`` section as read, for
    :class:`labrunner.safety_config.SafetyConfig` (``max_du_dt``, ``output_bounds``,
    ``input_bounds``, ``max_duration``, ...). ``info`` is the rig's :class:`RigInfo` with
    ``[limits]`` applied (set by the loader, :func:`labrunner.rigs.config.config_from_dict`).
    """

    name: str
    kind: str
    description: str = ""
    parameters: Mapping[str, Any] = field(default_factory=dict)
    limits: Mapping[str, Any] = field(default_factory=dict)
    noise: Mapping[str, Any] = field(default_factory=dict)
    faults: Faults = field(default_factory=Faults)
    safety: Mapping[str, Any] = field(default_factory=dict)
    source: str = "<dict>"
    info: RigInfo | None = field(default=None, compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form (for run metadata)."""
        f = self.faults
        faults = (
            {}
            if not f.any
            else {
                "t_start": f.t_start,
                "actuator_offset": list(f.actuator_offset),
                "actuator_gain": list(f.actuator_gain),
                "sensor_step": list(f.sensor_step),
            }
        )
        return {
            "rig": {"kind": self.kind, "name": self.name, "description": self.description, "source": self.source},
            "parameters": _jsonable(self.parameters),
            "limits": _jsonable(self.limits),
            "noise": _jsonable(self.noise),
            "faults": faults,
            "safety": _jsonable(self.safety),
        }


def _jsonable(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (tuple, list)):
        return [_jsonable(v) for v in x]
    return x


class Rig(abc.ABC):
    """A rig running B runs in lockstep. Use as a context manager so it always ends safe.

    Lifecycle: ``y0 = rig.reset(batch, seeds, fs)``, then ``y = rig.step(u)`` once per sample
    (zero-order hold of ``u`` over one sample; ``y`` is the measurement at the next sample),
    ``rig.safe_state(mask)`` for runs that tripped, and ``rig.close()``.

    **The clock.** A simulated rig has no clock of its own: the caller (the engine) decides when
    to call ``step`` and the rig advances its model by exactly 1/fs per call (``k`` counts the
    samples since ``reset``; ``k / fs`` is the rig's time, which the faults' ``t_start`` uses).
    A real rig's device is the clock: ``step`` sends the inputs of sample k and blocks until the
    device has measured sample k (:mod:`labrunner.rigs.transports.remote`).

    **Errors.** Bad input (a batch size, seeds, a sampling rate, an override or a rig-file value
    outside its range) raises :class:`~labrunner.errors.InvalidParameter` naming the field; a rig
    that cannot go on (device gone, bus off, watchdog, a fault frame) raises
    :class:`~labrunner.errors.RigError` after sending its runs to the safe state. Nothing else
    may escape ``reset``, ``step``, ``safe_state`` or ``close``.

    **The contract** (class attributes and class methods, used by the registry and the rig-file
    loader before any rig is built; each has a default where one is right):

    - ``PARAMETERS`` / ``NOISE``: ``{key: Param}`` schemas of the rig file's ``[parameters]`` and
      ``[noise]`` sections (default: none);
    - :meth:`validate_parameters`, :meth:`validate_noise`: check those sections (default: against
      the schemas; a kind with nested sections, like the remote rigs, overrides them);
    - :meth:`nominal_info` (abstract): what the rig is, from its validated parameters;
    - :meth:`overridable`: the keys a campaign may set per run (default: none), and
      :meth:`check_overrides`, which checks per-run values against them;
    - :meth:`from_config`: build the rig from a validated :class:`RigConfig` (default:
      ``cls(config.info, config.faults)``).
    """

    PARAMETERS: ClassVar[Schema] = {}
    NOISE: ClassVar[Schema] = {}

    # -- the contract (class methods) --------------------------------------------------------
    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        """The rig file's ``[parameters]`` checked and completed; InvalidParameter names ``path.key``."""
        return validate_section(cls.PARAMETERS, raw, path)

    @classmethod
    def validate_noise(cls, raw: Mapping[str, Any], path: str = "noise") -> dict[str, Any]:
        """The rig file's ``[noise]`` checked and completed; InvalidParameter names ``path.key``."""
        return validate_section(cls.NOISE, raw, path)

    @classmethod
    @abc.abstractmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        """Signals with their physical limits, sampling rates, safe input and nominal constants,
        from validated ``parameters`` (before the rig file's ``[limits]`` narrow them)."""

    @classmethod
    def overridable(cls) -> Schema:
        """Parameters a campaign may set per run (``[rig_parameters]``, grid axes): none by default."""
        return {}

    @classmethod
    def check_overrides(
        cls, config: RigConfig, overrides: Mapping[str, Any], batch: int, path: str = "overrides"
    ) -> dict[str, np.ndarray]:
        """Every numeric overridable parameter as a (B,) array, ``overrides`` applied and checked.

        An override is a scalar or a (B,) array; NaN entries keep the rig file's value for that
        run. Unknown keys and out-of-range values raise InvalidParameter naming ``path.key``.
        A kind with rules between parameters extends this (and checks them here, not in
        ``_reset``, so a campaign can check its points before anything runs).
        """
        schema = cls.overridable()
        _reject_unknown(schema, overrides, path)
        values = {**config.parameters, **config.noise}
        out = {k: np.full(batch, float(values[k])) for k, p in schema.items() if p.numeric}
        for key, value in overrides.items():
            out[key] = schema[key].check_array(f"{path}.{key}", value, batch, nominal=out.get(key))
        return out

    @classmethod
    def from_config(cls, config: RigConfig) -> Rig:
        """Build the rig a validated rig file describes (may raise RigError: a transport fails to open)."""
        if config.info is None:
            raise InvalidParameter("rig", f"{config.source}: the rig config has no RigInfo (use the loader)")
        return cls(config.info, config.faults)

    def __init__(self, info: RigInfo, faults: Faults | None = None) -> None:
        self.info = info
        self.faults = faults or Faults()
        self.batch = 0
        self.fs = info.fs_default
        self.k = 0  # samples stepped since reset
        self._safe = np.zeros(0, dtype=bool)
        self._safe_mask: np.ndarray | None = None  # (B, 1) view of _safe once any run is safe
        self._shape = (0, len(info.inputs))
        self.applied_input = np.zeros((0, len(info.inputs)))
        self._faulty = self.faults.any

    # -- public template methods -------------------------------------------------------------
    def reset(
        self,
        batch: int,
        seeds: Sequence[int] | np.ndarray,
        fs: float,
        overrides: Mapping[str, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Start B runs (per-run ``seeds`` and optional per-run parameter ``overrides``); return y0."""
        if batch < 1:
            raise InvalidParameter("batch", f"must be >= 1, got {batch}")
        seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
        if seeds.size != batch:
            raise InvalidParameter("seeds", f"need one seed per run ({batch}), got {seeds.size}")
        overrides = dict(overrides or {})
        _reject_unknown(self.overridable(), overrides, "overrides")  # before any state changes
        self.fs = self.info.check_fs(float(fs))
        self.batch = batch
        self.k = 0
        self._safe = np.zeros(batch, dtype=bool)
        self._safe_mask = None
        self._shape = (batch, len(self.info.inputs))
        self.applied_input = np.tile(np.asarray(self.info.safe_input, float), (batch, 1))
        self._faulty = self.faults.any  # decided once per batch, not every tick
        # per-tick constants at the batch's shape (ufuncs on equal shapes are cheapest)
        self._lo = np.tile(self.info.input_lo, (batch, 1))
        self._hi = np.tile(self.info.input_hi, (batch, 1))
        self._safe_input = self.applied_input.copy()
        y = self._reset(batch, seeds, overrides)
        return self._measure(np.asarray(y, dtype=float))

    def step(self, u: np.ndarray) -> np.ndarray:
        """Apply ``u`` (B, n_inputs) for one sample period; return the next measurement (B, n_outputs)."""
        u = np.asarray(u, dtype=float)
        if u.shape != self._shape:
            u = u.reshape(self._shape)
        u = clip(u, self._lo, self._hi)  # a new array
        safe = self._safe_mask
        if safe is not None:
            np.copyto(u, self._safe_input, where=safe)
        if self._faulty and self.k / self.fs >= self.faults.t_start:
            f = self.faults
            u = (1.0 + np.asarray(f.actuator_gain)) * u + np.asarray(f.actuator_offset)
            if safe is not None:
                np.copyto(u, self._safe_input, where=safe)
        self.applied_input = u
        y = self._step(u)
        self.k += 1
        return self._measure(np.asarray(y, dtype=float))

    def safe_state(self, mask: np.ndarray | None = None) -> None:
        """Send the runs in ``mask`` (all if None) to the safe state, at once and for good."""
        mask = np.ones(self.batch, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        self._safe |= mask
        self._safe_mask = self._safe[:, None] if self._safe.any() else None
        self.applied_input = np.where(self._safe[:, None], np.asarray(self.info.safe_input, float), self.applied_input)
        self._enter_safe_state(self._safe.copy())

    @property
    def is_safe(self) -> np.ndarray:
        """(B,) bool: runs held in the safe state."""
        return self._safe.copy()

    def close(self) -> None:
        """Leave every run safe and release the rig's resources."""
        if self.batch:
            self.safe_state()
        self._close()

    def __enter__(self) -> Rig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- backend hooks -------------------------------------------------------------------------
    @abc.abstractmethod
    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        """Initialise B runs (``overrides``' keys are known to be :meth:`overridable`; check their
        values with :meth:`check_overrides`); return the first measurement (B, n_outputs), noise
        included. Run i's noise must depend only on ``seeds[i]``. May raise RigError."""

    @abc.abstractmethod
    def _step(self, u: np.ndarray) -> np.ndarray:
        """Hold ``u`` (already clipped, safe-masked and faulted) for 1/fs s; return (B, n_outputs).

        A simulated rig advances by exactly one sample; a real one blocks until its device has
        measured the next sample. May raise RigError (after sending every run to the safe state)."""

    def _enter_safe_state(self, safe: np.ndarray) -> None:
        """Hook for real rigs to command the device's own safe state for runs in ``safe`` now.

        Best effort and must not raise: the base class already holds those runs at the safe input."""

    def _close(self) -> None:
        """Hook to release transports (called once by :meth:`close`, after every run is safe)."""

    # -- shared helpers ------------------------------------------------------------------------
    def _measure(self, y: np.ndarray) -> np.ndarray:
        if self._faulty and self.k / self.fs >= self.faults.t_start:
            y = y + np.asarray(self.faults.sensor_step)
        return y


def _reject_unknown(schema: Schema, overrides: Mapping[str, Any], path: str) -> None:
    unknown = sorted(set(overrides) - set(schema))
    if unknown:
        allowed = f"allowed: {', '.join(schema)}" if schema else "this rig has no per-run parameters"
        raise InvalidParameter(f"{path}.{unknown[0]}", f"unknown parameter; {allowed}")
