"""``labrunner run --dry-run``: what a campaign would run and about how long it would take.

Creates nothing: the points are planned and checked (:func:`labrunner.campaign.spec.plan`), and for
a simulated rig a prefix of one batch is run in-process to time the ticks.
"""

from __future__ import annotations

import json
import time

from labrunner.campaign.scheduler import make_batches
from labrunner.campaign.spec import Campaign, PlannedPoint


def grid_text(campaign: Campaign, points: list[PlannedPoint], slots: int, batch_size: int | None) -> str:
    """A grid campaign's point count, batches and an estimated time, as text; creates nothing."""
    requested = 1 if not campaign.rig_info.simulated else batch_size
    batches = make_batches([{"batch_key": p.batch_key, "point": p} for p in points], slots, requested)
    groups: dict[str, list[list[dict]]] = {}
    for key, members in batches:
        groups.setdefault(key, []).append(members)
    lines = [f"campaign {campaign.name}: {len(points)} points on rig {campaign.rig!r}, {len(batches)} batches"]
    total_s = 0.0
    for key, cut in groups.items():
        _, fs, duration, choices, *_ = json.loads(key)
        kind = dict(choices).get("controller.kind")
        sizes = [len(members) for members in cut]
        lines.append(
            f"  {sum(sizes)} points × {duration:g} s at {fs:g} Hz ({kind}{_per_run(cut)}): "
            f"{len(sizes)} batches of ≤ {max(sizes)}"
        )
        total_s += sum(sizes) * duration
    if campaign.rig_info.simulated:
        est = simulated_time(campaign, points, slots, batch_size)
        lines.append(
            f"  estimated time ≈ {est:.0f} s on {slots} worker(s) at this machine's present load "
            f"(timed now; {total_s:g} s of simulated time)"
        )
    else:
        from labrunner.rigs.device.plan import upload_s

        upload = upload_s(campaign, points)  # a device loop's samples sent after each run
        lines.append(
            f"  estimated time ≈ {total_s + upload + 2.0 * len(points):.0f} s on the real rig (one run at a time"
            + (f"; {upload:.0f} s of it sending samples after the runs)" if upload else ")")
        )
    return "\n".join(lines)


def _per_run(batches: list[list[dict]]) -> str:
    """The per-run choices of the runs of ``batches`` (rows with their planned batch key), e.g.
    ``; controller.input = v``, or ``; mixed batches: controller.input = v, force`` where they differ."""
    values: dict[str, list] = {}
    for row in (row for members in batches for row in members):
        key = json.loads(row["batch_key"])
        for path, value in key[5] if len(key) > 5 else ():
            values.setdefault(path, [])
            if value not in values[path]:
                values[path].append(value)
    mixed = any(len(v) > 1 for v in values.values())
    listed = "; ".join(f"{path} = {', '.join(map(str, v))}" for path, v in values.items())
    return f"; {'mixed batches: ' if mixed else ''}{listed}" if values else ""


def simulated_time(campaign: Campaign, points: list[PlannedPoint], slots: int, batch_size: int | None = None) -> float:
    """Seconds that ``points`` take on ``slots`` workers: their first batch (:func:`make_batches`, at
    most 16 of its runs) timed in-process (nothing written) and extrapolated."""
    from labrunner import engine
    from labrunner.rigs import registry

    _, batch = make_batches([{"batch_key": p.batch_key, "point": p} for p in points], slots, batch_size)[0]
    first = [row["point"] for row in batch[:: max(1, len(batch) // 16)][:16]]  # spread: early aborts end a batch early
    _, fs, duration, *_ = json.loads(first[0].batch_key)
    configs = []
    for p in first:
        config = campaign.resolve(p.parameters)
        config["campaign"]["duration"] = duration
        configs.append(config)
    probe_s = min(duration, max(0.5, 2000.0 / fs))  # a prefix of each run is enough to time the ticks
    t0 = time.perf_counter()
    with registry.load_rig(campaign.rig_ref, search=campaign.rig_search) as rig:
        engine.run_batch(
            configs, rig, fs=fs, duration=probe_s, seeds=[campaign.seed] * len(configs), rig_safety=campaign.rig_safety
        )
    per_run_sample = (time.perf_counter() - t0) / (len(first) * fs * probe_s)
    samples = sum(fs_d[0] * fs_d[1] for fs_d in (json.loads(p.batch_key)[1:3] for p in points))
    return per_run_sample * samples / slots + 0.01 * len(points)


def guided_text(campaign: Campaign, first: list[PlannedPoint], slots: int) -> str:
    """``--dry-run`` text: guided, the procedure, the maximum number of runs, an estimated time."""
    procedure = campaign.guided
    n = procedure.max_runs()
    _, fs, duration, *_ = json.loads(first[0].batch_key)
    lines = [
        f"campaign {campaign.name}: guided ({procedure.name}) on rig {campaign.rig!r}, at most {n} runs",
        f"  {procedure.describe()}",
        f"  first round: {len(first)} point(s) × {duration:g} s at {fs:g} Hz; later rounds follow from the outcomes",
    ]
    if campaign.rig_info.simulated:
        parallel = slots if len(first) > 1 else 1  # a walk runs one point per round
        per_run = simulated_time(campaign, first, 1) / len(first)
        rounds = n if len(first) == 1 else -(-n // len(first))  # each round costs a start-up of ~0.2 s
        lines.append(
            f"  estimated time ≤ {per_run * n / parallel + 0.2 * rounds:.0f} s for {n} runs on {parallel} worker(s) "
            f"(≤ {n * duration:g} s of simulated time)"
        )
    else:
        lines.append(f"  estimated time ≤ {n * (duration + 2.0):.0f} s on the real rig (one run at a time)")
    return "\n".join(lines)
