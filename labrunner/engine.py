"""Run engine: advances a batch of closed-loop runs tick by tick and classifies each run.

Per tick k (t = k/fs), for all B runs at once ("lockstep", see docs/architecture.md):
reference r[k] → controller u[k] = C(y[k], r[k]) → safety check of (u[k], y[k]) → tripped runs go
to the rig's safe state in this same tick → y[k+1] = rig.step(u[k]). A tripped run's signals end
at its abort sample; the batch goes on until every run has ended or the duration is reached.

Outcomes: ``completed``; ``aborted`` (a safety monitor tripped: monitor, time, value,
threshold); ``no-motion`` (completed, but the load never moved beyond the sensor resolution, or
the flow never rose above its threshold); ``failed`` (an exception: its message; a
:class:`~labrunner.errors.RigError` is re-raised after the runs are built, with them in
``exc.results``, so the worker keeps their logs up to the failure, then checks the rig). The same code
drives simulated twins and real rigs (B = 1); a real rig streams its samples to ``sink``. A
``progress`` hook hears the ticks done at most :data:`PROGRESS_CALLS` times a batch (the
campaign's live progress, :mod:`labrunner.campaign.live`), and a ``watch`` hook one run's samples
so far at the same times (the live view's signals); they cost one integer comparison a tick.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from labrunner._ufunc import count_nonzero
from labrunner.control import factory
from labrunner.control.base import Controller
from labrunner.control.trajectories import Reference
from labrunner.errors import LabrunnerError, RigError
from labrunner.metrics import Roles, closes_loop, parse_windows, run_metrics
from labrunner.rigs.base import Rig, RigInfo
from labrunner.safety import SafetyConfig, SafetyMonitor

_CHUNK = 1024  # reference samples evaluated at once, and samples per streamed block
PROGRESS_CALLS = 100  # a batch's progress hook is called at most this often (the last call: all ticks done)
Sink = Callable[[int, Mapping[str, np.ndarray]], None]
Progress = Callable[[int], None]  # ticks done of the batch's round(duration · fs)
Watch = Callable[[int, Mapping[str, np.ndarray], Mapping[str, object]], None]  # (first index, one run's rows, channels)


@dataclass(frozen=True)
class Outcome:
    """How a run ended. ``status`` ∈ completed | aborted | no-motion | failed."""

    status: str
    monitor: str | None = None
    time: float | None = None
    value: float | None = None
    threshold: float | None = None
    message: str = ""

    def as_dict(self) -> dict[str, object]:
        return {k: v for k, v in self.__dict__.items()}


@dataclass
class RunResult:
    """One run: outcome, signals (name → (K,) float64; sample k at k/fs), channel roles, metrics,
    and ``diagnostics`` a rig reports about the run (a device loop's timing and transfer), logged
    as the MCAP's ``diagnostics`` metadata; a real device's own timestamps (``device_clock``) are
    logged as the signal ``t_device``; ``float32_signals`` are logged as float32 (a device's samples
    are float32: stored exactly, in half the bytes)."""

    outcome: Outcome
    signals: dict[str, np.ndarray]
    fs: float
    channels: dict[str, object]  # role group → names, and "units" (see channel_names)
    metrics: dict[str, float] = field(default_factory=dict)
    diagnostics: dict[str, object] = field(default_factory=dict)
    device_clock: np.ndarray | None = None  # a real device's time of each sample [s since tick 0]; None: a twin
    float32_signals: tuple[str, ...] = ()  # signals whose values are float32 (a device's): logged as float32, exactly

    @property
    def n_samples(self) -> int:
        return len(next(iter(self.signals.values()))) if self.signals else 0


def channel_names(info: RigInfo, controller: Controller) -> dict[str, object]:
    """Signal names grouped by role, in the log's vocabulary (:func:`labrunner.logs.write_run`):
    ``outputs`` are the rig's measurements, ``controlled`` the tracked outputs computed from them
    (e.g. Ω from θ by (2.34)), plus ``units`` (SI unit per signal; references and errors share their output's)."""
    outputs, estimates = controller.output_names, controller.estimates
    est_names = []
    for name, value in estimates.items():
        if np.ndim(value) == 2:
            est_names += [f"{name}_{o}" for o in outputs]
        else:
            est_names.append(f"{name}_{outputs[0]}" if len(outputs) == 1 else name)
    measured = [s.name for s in info.outputs]
    units = {s.name: s.unit for s in (*info.outputs, *info.inputs)}
    for o, unit in zip(outputs, controller.output_units):
        units[o] = unit or units.get(o, "")
        units[f"ref_{o}"] = units[f"e_{o}"] = units[o]
    for name in est_names:
        estimate, _, o = name.rpartition("_")
        if o in outputs and estimate in ("e_hat", "de_hat", "f_hat") and controller.model_order:
            per_s = {"e_hat": 0, "de_hat": 1, "f_hat": controller.model_order}[estimate]
            units[name] = per_second(units[o], per_s)
    return {
        "outputs": measured,
        "controlled": [o for o in outputs if o not in measured],  # a measured one keeps role "output"
        "references": [f"ref_{o}" for o in outputs],
        "errors": [f"e_{o}" for o in outputs],
        "inputs": [s.name for s in info.inputs],
        "estimates": est_names,
        "units": units,
    }


_SUPERSCRIPT = {2: "²", 3: "³", 4: "⁴"}


def per_second(unit: str, n: int) -> str:
    """The unit of the n-th time derivative of a signal in ``unit``: ``per_second("rad/s", 1)`` is "rad/s²"."""
    if n == 0 or not unit:
        return unit
    base, m = unit, 0
    for power, suffix in ((1, "/s"), *((p, f"/s{sup}") for p, sup in _SUPERSCRIPT.items())):
        if unit.endswith(suffix):
            base, m = unit[: -len(suffix)], power
    total = m + n
    return f"{base}/s{_SUPERSCRIPT.get(total, '' if total == 1 else f'^{total}')}"


def _motion(config: SafetyConfig, rig: Rig, y: np.ndarray) -> bool:
    """Whether the run moved: ``y`` (K, n_rig_outputs) of one run."""
    names = [s.name for s in rig.info.outputs]
    j = names.index(config.motion_output) if config.motion_output else 0
    trace = y[:, j]
    if config.motion_min_level is not None:
        return bool(np.nanmax(trace) > config.motion_min_level)
    threshold = config.motion_min_change if config.motion_min_change is not None else rig.info.outputs[j].resolution
    return bool(np.nanmax(np.abs(trace - trace[0])) > threshold)


def run_batch(
    points: Sequence[Mapping[str, object]],
    rig: Rig,
    *,
    fs: float,
    duration: float,
    seeds: Sequence[int],
    rig_safety: Mapping[str, object] | None = None,
    sink: Sink | None = None,
    progress: Progress | None = None,
    reference: Reference | None = None,
    watch: Watch | None = None,
    watch_run: int = 0,
) -> list[RunResult]:
    """Run B = len(points) resolved campaign points in lockstep on ``rig``; return one result each.

    ``rig_safety`` is the rig file's ``[safety]`` section; each point's ``safety`` section
    overrides it. ``sink(first_index, block)`` receives run 0's samples every 1024 ticks (real rigs
    log while they run). ``progress(ticks_done)`` is called every ⌈K / PROGRESS_CALLS⌉ ticks and
    once when the loop ends (with K, also after an early end): at most PROGRESS_CALLS times;
    ``watch(first_index, rows, channels)`` at the same times run ``watch_run``'s samples since its
    last call, up to that run's end (``rows`` as ``sink``'s block, ``channels`` as
    :func:`channel_names`). Bad
    configuration raises :class:`~labrunner.errors.InvalidParameter` before the rig moves; an
    exception during the run marks every unfinished run ``failed``. ``reference`` replaces the
    points' references (a device runs its description's sample tables).
    """
    B = len(points)
    K = int(round(duration * fs))
    controller, built = factory.build(points, rig.info, fs)
    reference = built if reference is None else reference
    configs = _safety_configs(points, rig.info, rig_safety or {})
    overrides = _overrides(points)
    monitor = SafetyMonitor(configs, rig.info, fs)

    log = _TickLog(K, B, rig, controller)
    u_log, y_log, c_log, r_log, est_pairs = log.u, log.y, log.c, log.r, log.estimates
    end = np.full(B, K)  # samples recorded per run
    active = np.ones(B, dtype=bool)
    failure = ""
    rig_error: RigError | None = None
    k = logged = 0  # logged: ticks whose row is complete in every log
    every = -(-K // PROGRESS_CALLS) if K else 1
    report_at = every if progress is not None or watch is not None else K  # K: never inside the loop
    watched = 0  # run watch_run's samples handed to ``watch``

    try:
        y = rig.reset(B, seeds, fs, overrides)
        controller.reset(y)
        monitor.reset(rig.applied_input)
        r_chunk = np.empty(0)
        finished = False  # every run has ended
        for k in range(K):
            if k == report_at:
                if progress is not None:
                    progress(k)
                if watch is not None:
                    watched = _watch(watch, log, watch_run, watched, min(k, int(end[watch_run])))
                report_at += every
            if k % _CHUNK == 0:
                r_chunk = reference.evaluate(np.arange(k, min(k + _CHUNK, K)) / fs)
                r_log[k : k + len(r_chunk)] = r_chunk[..., 0]
            r = r_chunk[k % _CHUNK]
            u = controller.step(y, r)
            u_log[k], y_log[k] = u, y
            tripped = monitor.check(k, u, y, active)
            if count_nonzero(tripped):
                rig.safe_state(tripped)
                end[tripped] = k + 1
                active &= ~tripped
                finished = not count_nonzero(active)
            c_log[k] = controller.controlled
            for est_log, value in est_pairs:
                est_log[k] = value
            logged = k + 1
            if sink is not None and (k + 1) % _CHUNK == 0:
                sink(k + 1 - _CHUNK, log.signals(log.rows(0, k + 1 - _CHUNK, k + 1)))
            if finished:
                break
            y = rig.step(u)
    except RigError as exc:  # the rig failed: fail the open runs, keep what was logged, re-raise below
        rig.safe_state()
        rig_error, failure = exc, f"RigError: {exc}"
        log.blank(logged)
        end = np.where(active, np.minimum(end, k + 1), end)
    except LabrunnerError:
        rig.safe_state()
        raise
    except Exception as exc:  # a crash of the controller, the rig or the twin: fail the open runs
        rig.safe_state()
        failure = f"{type(exc).__name__}: {exc}"
        log.blank(logged)
        end = np.where(active, np.minimum(end, k + 1), end)
    else:
        rig.safe_state()
    if progress is not None:
        progress(K)
    if watch is not None:
        _watch(watch, log, watch_run, watched, int(end[watch_run]))
    if sink is not None and int(end[0]) % _CHUNK:  # run 0's samples after its last full chunk
        last = int(end[0]) - int(end[0]) % _CHUNK
        sink(last, log.signals(log.rows(0, last, int(end[0]))))

    channels = log.channels
    roles = roles_of(channels, rig.info if closes_loop(points[0]) else None)  # a batch shares its controller kind
    results = []
    by_run = log.run_major(int(end.max()) if B else 0)
    for i in range(B):
        n = int(end[i])
        signals = log.signals([part[i, :, :n] for part in by_run])
        if failure and active[i]:
            outcome = Outcome("failed", message=failure)
        elif monitor.verdicts[i] is not None:
            v = monitor.verdicts[i]
            outcome = Outcome("aborted", v.monitor, v.time, v.value, v.threshold)
        elif not _motion(configs[i], rig, by_run[0][i, log.y_columns, :n].T):
            outcome = Outcome("no-motion", message="the load never moved beyond the sensor resolution")
        else:
            outcome = Outcome("completed")
        metrics = run_metrics(signals, roles, fs=float(fs), windows=parse_windows(points[i].get("metrics")))
        results.append(RunResult(outcome, signals, float(fs), channels, metrics))
    if rig_error is not None:  # the worker publishes these logs of the failed runs, then checks the rig
        rig_error.results = results
        raise rig_error
    return results


def _watch(watch: Watch, log: _TickLog, run: int, lo: int, hi: int) -> int:
    """Hand run ``run``'s samples lo..hi−1 to ``watch``; the samples handed so far."""
    if hi > lo:
        watch(lo, log.signals(log.rows(run, lo, hi)), log.channels)
    return max(lo, hi)


def roles_of(channels: Mapping[str, object], info: RigInfo | None = None) -> Roles:
    """The metrics' signal roles from a result's channel groups (:func:`channel_names`); with the
    rig's ``info``, its input limits for the oscillation detector."""
    return Roles(
        errors=tuple(channels["errors"]),
        inputs=tuple(channels["inputs"]),  # type: ignore[arg-type]
        error_hats=tuple(n for n in channels["estimates"] if n.startswith("e_hat_")),  # type: ignore[union-attr]
        currents=tuple(n for n, unit in channels["units"].items() if unit == "A"),  # type: ignore[union-attr]
        input_limits=tuple((s.lo, s.hi) for s in info.inputs) if info is not None else (),
    )


def _safety_configs(
    points: Sequence[Mapping[str, object]], info: RigInfo, rig_safety: Mapping[str, object]
) -> list[SafetyConfig]:
    """Each point's validated limits; points with equal ``safety`` sections share one (a campaign's
    points mostly do: validating each costs ~0.1 ms a run)."""
    by_section: dict[str, SafetyConfig] = {}
    configs = []
    for p in points:
        section = dict(p.get("safety", {}) or {})
        key = repr(section)
        if key not in by_section:
            by_section[key] = SafetyConfig.from_sections(info, rig_safety, section)
        configs.append(by_section[key])
    return configs


def _overrides(points: Sequence[Mapping[str, object]]) -> dict[str, np.ndarray]:
    """Per-run rig parameter overrides from each point's ``rig_parameters`` section."""
    keys = sorted({k for p in points for k in dict(p.get("rig_parameters", {}) or {})})
    return {k: np.array([float(dict(p.get("rig_parameters", {}) or {}).get(k, np.nan)) for p in points]) for k in keys}


def _run_first(ndim: int, run_axis: int) -> tuple[int, ...]:
    """Axes of a (tick, ...) log in the order run, the other axes, tick."""
    return (run_axis, *(a for a in range(1, ndim) if a != run_axis), 0)


class _TickLog:
    """Every logged signal of a batch, one row per tick and log part, each part as its producer
    hands it over: u and y side by side (``io``), the controlled
    outputs ``c``, the references ``r`` and the estimates (``estimates``: pairs of a log and the
    controller's live array; one block when the controller keeps them so). Rows are read only up
    to each run's end, so they need no fill. Columns of a run, in order: inputs, measured
    outputs, controlled outputs, references, estimates.
    """

    def __init__(self, K: int, B: int, rig: Rig, controller: Controller) -> None:
        n_in, n_meas, n_out = len(rig.info.inputs), len(rig.info.outputs), controller.n_outputs
        self.channels = channel_names(rig.info, controller)
        self._outputs = controller.output_names
        self._measured = [s.name for s in rig.info.outputs]
        self.io = np.empty((K, B, n_in + n_meas))
        self.u, self.y = self.io[:, :, :n_in], self.io[:, :, n_in:]
        self.y_columns = slice(n_in, n_in + n_meas)
        self.c, self.r = np.empty((K, B, n_out)), np.empty((K, B, n_out))
        block = controller.estimate_block
        live = [block] if block is not None else list(controller.estimates.values())
        self.estimates = [(np.empty((K,) + np.shape(v)), v) for v in live]
        # (log, its axes ordered run, columns..., tick); a block's log (K, n, B, ...) has the runs on axis 2
        run_axis = 2 if block is not None else 1
        self._parts = [(part, _run_first(part.ndim, 1)) for part in (self.io, self.c, self.r)]
        self._parts += [(e, _run_first(e.ndim, run_axis)) for e, _ in self.estimates]

    def blank(self, start: int) -> None:
        """NaN from tick ``start`` on (a failure: that tick's row may be partly written)."""
        for part, _ in self._parts:
            part[start:] = np.nan

    def rows(self, run: int, lo: int, hi: int) -> list[np.ndarray]:
        """Run ``run``'s samples lo..hi−1 per part, (columns, hi − lo) views."""
        return [part[lo:hi].transpose(axes)[run].reshape(-1, hi - lo) for part, axes in self._parts]

    def run_major(self, n: int) -> list[np.ndarray]:
        """Per part, a (B, columns, n) copy of the first n ticks with each run's signals contiguous."""
        return [
            np.ascontiguousarray(part[:n].transpose(axes)).reshape(part.shape[axes[0]], -1, n)
            for part, axes in self._parts
        ]

    def signals(self, parts: list[np.ndarray]) -> dict[str, np.ndarray]:
        """The named traces of one run from its rows per part (see docs/architecture.md for the
        naming): views of the rows, plus the errors e = y − y_r."""
        rows = [row for part in parts for row in part]
        inputs, estimates = self.channels["inputs"], self.channels["estimates"]
        n_in, n_meas, n_out = len(inputs), len(self._measured), len(self._outputs)
        sig = dict(zip(self._measured, rows[n_in : n_in + n_meas]))
        sig.update(zip(inputs, rows[:n_in]))
        c0 = n_in + n_meas
        for j, o in enumerate(self._outputs):
            sig[o], sig[f"ref_{o}"] = rows[c0 + j], rows[c0 + n_out + j]
            sig[f"e_{o}"] = sig[o] - sig[f"ref_{o}"]
        sig.update(zip(estimates, rows[c0 + 2 * n_out :]))
        return sig
