"""Host side of device-loop runs: campaign points → run descriptions → ordinary RunResults.

:func:`plan` builds (and so checks) every point's description before the rig moves; :func:`run`
sends them one after the other over a bulk link and turns each device answer into the
:class:`~labrunner.engine.RunResult` the twin engine would have returned — same signal names and
roles, metrics computed by the same code from the float32 samples — with the device's timing
and the transfer's figures in ``RunResult.diagnostics`` (the MCAP's ``diagnostics`` metadata).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from labrunner import engine
from labrunner.control import factory
from labrunner.metrics import closes_loop, parse_windows, run_metrics
from labrunner.rigs.base import RigInfo
from labrunner.rigs.device import blocks, description, lawcheck, session
from labrunner.rigs.device.columns import column_names, from_columns
from labrunner.rigs.transports import linkload


def plan(
    points: Sequence[Mapping[str, object]],
    rig_info: RigInfo,
    *,
    fs: float,
    duration: float,
    seeds: Sequence[int],
    rig_safety: Mapping[str, object] | None,
    watchdog_s: float = 0.5,
    link: linkload.LinkSpec | None = None,
    reference_table: bool = False,
) -> list[bytes]:
    """One encoded description per point (raises InvalidParameter for one the device cannot run).
    With ``link``, each says whether its samples stream during the run (they fit the link);
    ``reference_table`` sends the references as sample tables."""
    out = []
    for point, seed in zip(points, seeds):
        data = description.build(
            point,
            rig_info,
            fs=fs,
            duration=duration,
            seed=seed,
            rig_safety=rig_safety,
            watchdog_s=watchdog_s,
            reference_table=reference_table,
        )
        if (
            link is not None
            and linkload.device_loop_load(link, fs, description.decode(data).n_columns) <= linkload.MAX_LOAD
        ):
            data = description.with_stream(data, True)
        out.append(data)
    return out


def to_result(
    point: Mapping[str, object],
    rig_info: RigInfo,
    fs: float,
    verdict: blocks.Verdict,
    rows: np.ndarray,
    diagnostics: Mapping[str, object],
) -> engine.RunResult:
    """The RunResult of one device run, named and measured as the engine names and measures a twin run."""
    controller, _ = factory.build([point], rig_info, fs)
    channels = engine.channel_names(rig_info, controller)
    if rows.shape[1] != len(column_names(channels)):
        raise ValueError(f"{rows.shape[1]} columns for {len(column_names(channels))} signals")
    signals = from_columns(rows, channels)

    def opt(x: float) -> float | None:
        return None if math.isnan(x) else float(x)

    outcome = engine.Outcome(
        verdict.status,
        verdict.monitor or None,
        opt(verdict.time),
        opt(verdict.value),
        opt(verdict.threshold),
        verdict.message,
    )
    metrics = run_metrics(
        signals,
        engine.roles_of(channels, rig_info if closes_loop(point) else None),
        fs=float(fs),
        windows=parse_windows(point.get("metrics")),
    )  # as the engine measures a twin run
    result = engine.RunResult(outcome, signals, float(fs), channels, metrics, dict(diagnostics))
    result.float32_signals = tuple(signals)  # every column came from the device's float32 rows
    return result


def run(
    send: session.Send,
    recv: session.Recv,
    max_payload: int,
    points: Sequence[Mapping[str, object]],
    rig_info: RigInfo,
    *,
    fs: float,
    duration: float,
    seeds: Sequence[int],
    rig_safety: Mapping[str, object] | None = None,
    watchdog_s: float = 0.5,
    link: linkload.LinkSpec | None = None,
    dead_s: float = session.DEAD_S,
    reference_table: bool = False,
    arithmetic: str = lawcheck.FLOAT64,
) -> list[engine.RunResult]:
    """Run ``points`` on the device one after the other; one RunResult each.

    A run the host gives up on (:class:`~labrunner.rigs.device.session.RunFailed`) stops the
    batch: the RigError is re-raised with ``results``, the finished runs and the failed one as a
    ``failed`` RunResult of the rows that had arrived (its partial log, the reason as its message),
    as :func:`labrunner.engine.run_batch` hands over a host-loop run's. Every run, the failed one
    too (up to its last row), carries its law check, with the tolerance of ``arithmetic`` (the
    device's: float64, or float32 where it announces FLOAT32)."""
    descriptions = plan(
        points,
        rig_info,
        fs=fs,
        duration=duration,
        seeds=seeds,
        rig_safety=rig_safety,
        watchdog_s=watchdog_s,
        link=link,
        reference_table=reference_table,
    )
    results = []
    for point, seed, data in zip(points, seeds, descriptions):
        d = description.decode(data)
        diagnostics = {"loop": "device", "description_bytes": len(data), "columns": d.n_columns, "streamed": d.stream}
        try:
            verdict, rows, clock, transfer = session.run_on_device(
                send, recv, max_payload, data, d.ticks, d.n_columns, d.fs, dead_s=dead_s
            )
        except session.RunFailed as exc:
            failed = blocks.Verdict("failed", len(exc.rows), len(exc.rows), 0, message=f"RigError: {exc}")
            partial = to_result(point, rig_info, fs, failed, exc.rows, diagnostics)
            partial.device_clock = exc.clock
            law = lawcheck.check(
                point, rig_info, exc.rows, partial.outcome, fs=fs, duration=duration, seed=seed,
                rig_safety=rig_safety, arithmetic=arithmetic,
            )  # fmt: skip
            partial.diagnostics["law_check"] = law.as_dict()
            exc.results = [*results, partial]
            raise
        diagnostics.update(
            ticks=verdict.ticks,
            overruns=verdict.overruns,
            device_run_s=verdict.device_us / 1e6,
            device_compute_s=verdict.compute_ns / 1e9,
            **transfer.as_dict(),
        )
        result = to_result(point, rig_info, fs, verdict, rows, diagnostics)
        result.device_clock = clock
        law = lawcheck.check(
            point, rig_info, rows, result.outcome, fs=fs, duration=duration, seed=seed, rig_safety=rig_safety,
            arithmetic=arithmetic,
        )  # fmt: skip
        result.diagnostics["law_check"] = law.as_dict()
        results.append(result)
    return results
