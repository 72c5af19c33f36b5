"""The one Rig interface every rig speaks: simulated twins and real rigs over CAN or serial.

A rig advances a *batch* of B independent runs in lockstep (B = 1 for a real rig). Arrays have a
leading batch axis: inputs ``u`` are ``(B, n_inputs)``, measurements ``y`` are ``(B, n_outputs)``.

The public methods are template methods (python-can's ``BusABC`` pattern): the base class does
what every rig must do the same way — input clipping to the rig's limits, the safe state of
tripped runs, actuator and sensor faults, the sample clock — and a backend implements only
``_reset`` and ``_step``.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from labrunner._ufunc import clip
from labrunner.errors import InvalidParameter


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


class Rig(abc.ABC):
    """A rig running B runs in lockstep. Use as a context manager so it always ends safe.

    Lifecycle: ``y0 = rig.reset(batch, seeds, fs)``, then ``y = rig.step(u)`` once per sample
    (zero-order hold of ``u`` over one sample; ``y`` is the measurement at the next sample),
    ``rig.safe_state(mask)`` for runs that tripped, and ``rig.close()``.
    """

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
        y = self._reset(batch, seeds, dict(overrides or {}))
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
        """Initialise B runs; return the noise-free-or-not first measurement (B, n_outputs)."""

    @abc.abstractmethod
    def _step(self, u: np.ndarray) -> np.ndarray:
        """Hold ``u`` (already clipped, safe-masked and faulted) for 1/fs s; return (B, n_outputs)."""

    def _enter_safe_state(self, safe: np.ndarray) -> None:
        """Hook for real rigs to command the device's own safe state for runs in ``safe`` now."""

    def _close(self) -> None:
        """Hook to release transports."""

    # -- shared helpers ------------------------------------------------------------------------
    def _measure(self, y: np.ndarray) -> np.ndarray:
        if self._faulty and self.k / self.fs >= self.faults.t_start:
            y = y + np.asarray(self.faults.sensor_step)
        return y
