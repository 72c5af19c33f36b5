"""A synthetic campaign directory (ledger + MCAP logs) for the analysis tests, without the engine.

Outcomes follow a hand-made rule over a γ–k_p grid so tests know what each marker must be; the
signals are chosen so that each run's metrics are known in closed form:
e_omega[k] = c (constant) → RMS = |c|; u[k] = ±v alternating → E(u) = K v², max |u| = v.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from labrunner.analysis.table import roles_of
from labrunner.campaign.ledger import Ledger, RunRecord
from labrunner.logs import write_run
from labrunner.metrics import run_metrics

CHANNELS = {
    "omega": {"role": "controlled", "unit": "rad/s"},
    "ref_omega": {"role": "reference", "unit": "rad/s"},
    "e_omega": {"role": "error", "unit": "rad/s"},
    "u": {"role": "input", "unit": "V"},
    "theta": {"role": "output", "unit": "rad"},
    "f_hat_omega": {"role": "estimate", "unit": "rad/s²"},
}
FS = 200.0
K = 400


def outcome_of(gamma: float, k_p: float) -> str:
    """Aborted above k_p = γ/2 (a made-up bound), no motion when γ/k_p > 1000, else completed."""
    if k_p > gamma / 2:
        return "aborted"
    if gamma / k_p > 1000:
        return "no-motion"
    return "completed"


def expected_metrics(gamma: float, k_p: float) -> tuple[float, float, float]:
    """(RMS of e, E(u), max |u|) of the synthetic run at (γ, k_p), over its n samples."""
    n = K // 4 if outcome_of(gamma, k_p) == "aborted" else K
    c, v = gamma / k_p / 100.0, min(12.0, k_p / 10.0)
    return c, n * v * v, v


def make_campaign(
    directory: Path,
    *,
    gammas=(1.0, 10.0, 100.0, 1000.0),
    k_ps=(0.1, 1.0, 10.0, 100.0),
    meta: dict[str, str] | None = None,
    legacy: bool = False,
) -> list[dict]:
    """Plan, run (synthetically) and commit every point with its metrics, as the engine does; return
    the points' parameters and ids. ``legacy``: commit only the three summary metrics, as ledgers
    did before every metric was committed (the analysis must then read the logs)."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "runs").mkdir(exist_ok=True)
    points = []
    for i, (g, kp) in enumerate((g, kp) for g in gammas for kp in k_ps):
        points.append({"seq": i, "id": f"p{i:04d}", "params": {"controller.gamma": g, "controller.k_p": kp}})
    ledger = Ledger.create(
        directory,
        meta=meta or {"campaign": "synthetic"},
        points=[(p["seq"], p["id"], p["params"], "b") for p in points],
    )
    with ledger:
        ledger.claim([p["id"] for p in points])
        for p in points:
            g, kp = p["params"]["controller.gamma"], p["params"]["controller.k_p"]
            status = outcome_of(g, kp)
            n = K // 4 if status == "aborted" else K
            c, _, v = expected_metrics(g, kp)
            u = v * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
            signals = {
                "omega": np.full(n, 1.0),
                "ref_omega": np.full(n, 1.0 - c),
                "e_omega": np.full(n, c),
                "u": u,
                "theta": np.cumsum(np.full(n, 1.0 / FS)),
                "f_hat_omega": np.zeros(n),
            }
            outcome = {"status": status}
            if status == "aborted":
                outcome.update(monitor="du_dt", time=(n - 1) / FS, value=150.0, threshold=120.0)
            rel = f"runs/{p['id']}.mcap"
            write_run(
                directory / rel,
                metadata={"run": {"point_id": p["id"]}, "config": {"controller": {"gamma": g, "k_p": kp}}},
                fs=FS,
                signals=signals,
                outcome=outcome,
                channels=CHANNELS,
            )
            metrics = run_metrics(signals, roles_of(CHANNELS))
            ledger.commit(RunRecord(p["id"], status, outcome, metrics, rel, "host", 1, time.time()))
    if legacy:
        with Ledger.open(directory) as ledger:
            ledger.db.execute("UPDATE points SET metrics_json = NULL")
    return points


def tear(path: Path, keep: float = 0.6) -> None:
    """Cut a log file short, as a killed writer leaves it."""
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def params_json(p: dict) -> str:
    return json.dumps(p["params"], sort_keys=True)
