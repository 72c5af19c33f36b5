"""The device firmware's reference executor: a run description in, the logged samples and the
verdict out (pure: the rig it drives is passed in, samples go to a callback).

It runs the ONE closed loop there is, :func:`labrunner.engine.run_batch` at B = 1, on the point the
description's parameter records rebuild, so a device-loop run of a point gives the twin's result
for that point. Before it runs, it checks that the records a firmware computes with (FIR weights,
saturation, resolved reference segments, column count) equal what the engine's factory builds
from that point: a description whose two halves disagree is refused, so firmware implementing
the records runs the law the engine runs.

The emulated device's clock is virtual: tick k is at k/f_s device time whatever the host
computer's speed (a Python twin of the plate runs slower than 32 kHz), so it never overruns;
``compute_ns`` says how long the run really took.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from labrunner import engine
from labrunner.control import factory
from labrunner.control.trajectories import Reference
from labrunner.rigs.base import Rig
from labrunner.rigs.device import blocks, doclaw, lawrecords
from labrunner.rigs.device.columns import column_names, to_columns
from labrunner.rigs.device.description import (
    DEVICE_KINDS,
    FIR_CONTROLLER,
    T_TABLE,
    Description,
    DescriptionError,
    decode,
    executed_trajectories,
    filter_matrices,
    rig_safety,
    trajectory_record,
)
from labrunner.rigs.device.replay import ReplayRig
from labrunner.safety import SafetyConfig

#: ``hook(first_tick, columns)``: every 1024 ticks during the run, float32 rows of those ticks
Hook = Callable[[int, np.ndarray], None]
#: ``tick(k)``: every :data:`TICK_EVERY` ticks, the ticks done (the firmware's main-loop turn:
#: PROGRESS, the link, STOP and the watchdog; however slowly the twin computes)
Tick = Callable[[int], None]
TICK_EVERY = 32


class _Ticking:
    """``rig`` whose :meth:`step` calls ``tick(k)`` every :data:`TICK_EVERY` ticks; all else is the rig's."""

    def __init__(self, rig: Rig, tick: Tick) -> None:
        self._rig, self._tick, self._k = rig, tick, 0

    def __getattr__(self, name: str):
        return getattr(self._rig, name)

    def step(self, u: np.ndarray) -> np.ndarray:
        self._k += 1
        if self._k % TICK_EVERY == 0:
            self._tick(self._k)
        return self._rig.step(u)


@dataclass
class DeviceRun:
    """A finished device run: its rows (K, n_columns) float32, the verdict, its channel groups."""

    columns: np.ndarray
    verdict: blocks.Verdict
    channels: Mapping[str, object]


def check(description: Description, rig: Rig) -> dict[str, object]:
    """The channel groups of the described run on ``rig``; raises DescriptionError where the
    description does not fit this device or its firmware records disagree with its point."""
    return _check(description, rig)[0]


def _check(description: Description, rig: Rig) -> tuple[dict[str, object], Reference]:
    """:func:`check`'s channel groups, and the reference the device runs (its sample tables)."""
    info = rig.info
    if (description.n_inputs, description.n_outputs) != (len(info.inputs), len(info.outputs)):
        raise DescriptionError(
            f"description for {description.n_inputs} inputs and {description.n_outputs} outputs; "
            f"this {info.kind} has {len(info.inputs)} and {len(info.outputs)}"
        )
    if description.kind not in DEVICE_KINDS:
        raise DescriptionError(f"controller kind {description.kind!r} is not in this firmware")
    point = description.point()
    try:
        controller, reference = factory.build([point], info, description.fs)
    except Exception as exc:
        raise DescriptionError(f"the description's point does not build: {exc}") from None
    channels = engine.channel_names(info, controller)
    if len(column_names(channels)) != description.n_columns:
        raise DescriptionError(
            f"description asks for {description.n_columns} columns, the run logs {len(column_names(channels))}"
        )
    order = DEVICE_KINDS[description.kind]
    if order is not None and point.get("differentiator"):
        design = factory.differentiators([point], description.fs, order)[0]
        for n in range(order + 1):
            sent = description.fir.get((FIR_CONTROLLER, n))
            if sent is None or not np.array_equal(sent, design.weights(n)):
                raise DescriptionError(f"FIR weights of derivative order {n} differ from the point's design")
    if description.saturation is None or not (
        np.array_equal(description.saturation[0], controller.u_min[0])
        and np.array_equal(description.saturation[1], controller.u_max[0])
    ):
        raise DescriptionError("input saturation differs from the point's")
    mine = filter_matrices(controller)
    if mine.keys() != description.filters.keys() or any(
        not np.array_equal(mine[k], description.filters[k]) for k in mine
    ):
        raise DescriptionError("filter matrices differ from the point's controller")
    law = lawrecords.law_constants(controller)
    if law.keys() != description.law.keys() or any(not np.array_equal(law[k], description.law[k]) for k in law):
        raise DescriptionError("law constants differ from the point's controller")
    try:
        config = SafetyConfig.from_sections(info, rig_safety(description), dict(point.get("safety") or {}))
    except Exception as exc:
        raise DescriptionError(f"the description's safety sections do not build: {exc}") from None
    if description.motion != lawrecords.motion_rule(config, info):
        raise DescriptionError("the no-motion rule differs from the point's")
    table = description.sensor_table
    if table is not None and table.shape[1] != len(info.outputs):
        raise DescriptionError(f"sensor table of {table.shape[1]} outputs; this {info.kind} has {len(info.outputs)}")
    rows = reference.trajectories[0]
    sent = description.trajectories
    expected = [
        trajectory_record(t, description.fs, description.ticks, table=code == T_TABLE)
        for t, (code, _) in zip(rows, sent)
    ]
    if len(rows) != len(sent) or any(
        code != c or len(a) != len(b) or any(not np.array_equal(x, y) for x, y in zip(a, b))
        for (code, a), (c, b) in zip(expected, description.trajectories)
    ):
        raise DescriptionError("reference segments differ from the point's reference")
    return channels, Reference([executed_trajectories(description, rows)])


def execute(
    data: bytes,
    rig: Rig,
    hook: Hook | None = None,
    on_accept: Callable[[Description], None] | None = None,
    tick: Tick | None = None,
    law_fault: Mapping[str, float] | None = None,
) -> DeviceRun:
    """Decode, check and run one description on ``rig`` (B = 1); raises DescriptionError for a
    description the device refuses (before the rig moves). ``on_accept(description)`` is called
    once it is checked, before the first tick; ``hook`` gets the samples, ``tick`` the ticks done
    (an exception from either ends the run ``failed`` with its message, the rig safe). A
    description with a sensor table runs on that table instead of the rig (nothing moves).
    ``law_fault`` (controller key → factor) makes the device run a deliberately wrong law — the
    emulator's ``--fault-law``: each key the point's controller section sets is multiplied by its
    factor after the checks."""
    description = decode(data)
    channels, reference = _check(description, rig)
    point = description.point()
    for key, factor in (law_fault or {}).items():
        if key in point["controller"]:
            point["controller"][key] = float(point["controller"][key]) * factor  # type: ignore[index]
    if description.sensor_table is not None:
        rig = ReplayRig(rig.info, description.sensor_table[None], hold_last=True)
    if on_accept is not None:
        on_accept(description)
    sink = None
    if hook is not None:

        def sink(first: int, signals: Mapping[str, np.ndarray]) -> None:
            hook(first, to_columns(signals, channels))

    t0 = time.perf_counter_ns()
    result = engine.run_batch(
        [point],
        rig if tick is None else _Ticking(rig, tick),
        fs=description.fs,
        duration=description.duration,
        seeds=[description.seed],
        rig_safety=rig_safety(description),
        sink=sink,
        reference=reference,
    )[0]
    compute_ns = time.perf_counter_ns() - t0
    n = result.n_samples
    o = result.outcome
    verdict = blocks.Verdict(
        o.status, n, n, 0, o.monitor or "",
        *(float("nan") if v is None else float(v) for v in (o.time, o.value, o.threshold)),
        message=o.message, device_us=blocks.tick_us(n, description.fs), compute_ns=compute_ns,
    )  # fmt: skip
    return DeviceRun(to_columns(result.signals, channels), verdict, channels)


def execute_document(
    data: bytes,
    rig: Rig,
    hook: Hook | None = None,
    on_accept: Callable[[Description], None] | None = None,
    tick: Tick | None = None,
    law_fault: Mapping[str, float] | None = None,
    dtype: type = np.float32,
) -> DeviceRun:
    """:func:`execute` with the law of :mod:`~labrunner.rigs.device.doclaw` computed in ``dtype``
    (``labrunner emulate --float32``: a single-precision firmware) instead of the engine's loop.
    The same checks first; ``law_fault`` multiplies the LAW record of each key; the samples go to
    ``hook`` once the run has ended (in blocks of 1024 ticks)."""
    description = decode(data)
    channels, _ = _check(description, rig)
    for key, factor in (law_fault or {}).items():
        if key in description.law:
            description.law[key] = description.law[key] * factor
    if on_accept is not None:
        on_accept(description)
    measure = None
    if description.sensor_table is None:

        def measure(k: int, u: np.ndarray) -> np.ndarray:
            if k == 0:
                return rig.reset(1, [description.seed], description.fs)[0]
            return rig.step(u[None])[0]

    t0 = time.perf_counter_ns()
    names = ([s.name for s in rig.info.inputs], [s.name for s in rig.info.outputs])
    try:
        rows, v = doclaw.run(description, *names, dtype=dtype, measure=measure, tick=tick)
    finally:
        if description.sensor_table is None:
            rig.safe_state()
    compute_ns = time.perf_counter_ns() - t0
    columns = rows.astype(np.float32)
    n = len(columns)
    if hook is not None:
        for first in range(0, n, 1024):
            hook(first, columns[first : first + 1024])
    verdict = blocks.Verdict(
        v["status"], n, n, 0, str(v.get("monitor", "")),
        *(float(v.get(key, float("nan"))) for key in ("time", "value", "threshold")),
        message=str(v.get("message", "")), device_us=blocks.tick_us(n, description.fs), compute_ns=compute_ns,
    )  # fmt: skip
    return DeviceRun(columns, verdict, channels)
