"""A synthetic ledger of a large motor γ–k_p campaign (the quickstart's, n_γ × n_k_p points) for
measuring ``status``, ``resume`` and ``analyse`` at 10^6 points without running 10^6 simulations.

The ledger is what ``labrunner run`` writes — the campaign copy, its meta (including the plan-inputs
digest), one row per grid point with the point's real id and parameters, in grid order — except
that the plan's static checks are not run (``plan_checksum`` says so) and the finished rows are
the rows of a small real run (``labrunner run`` of a 4 × 4 quickstart) repeated. Their logs are
that run's 16 logs, hard-linked (no disk a point; ext4 allows 65 000 links a file, enough for
10^6 points), each row recording its log's fingerprint as the worker does: ``analyse`` takes them
as proved (their metadata names the small run's points, so an ``analyse`` that read them would
call them foreign) and reads only the few it plots. The directory is sealed as a ``run`` that
ended cleanly leaves it (:mod:`labrunner.campaign.seal`). ``finished`` is the fraction of points
marked finished (grid order); the rest stay planned, as after an interrupted run.
"""

from __future__ import annotations

import itertools
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_campaign import campaign  # noqa: E402

from labrunner.campaign import plan_inputs, seal, spec  # noqa: E402
from labrunner.campaign.grid import point_id  # noqa: E402
from labrunner.campaign.ledger import Ledger  # noqa: E402
from labrunner.campaign.runner import CAMPAIGN_COPY  # noqa: E402
from labrunner.campaign.status import REAL_RIG  # noqa: E402
from labrunner.run_identity import FINGERPRINT_COLUMNS, fingerprint  # noqa: E402

ROW_COLUMNS = ("state", "outcome", "outcome_json", "rms_error", "input_energy", "max_abs_input", "metrics_json")


def template_rows(logs: Path) -> list[tuple]:
    """The finished rows of a real 16-point quickstart run (its ROW_COLUMNS, plus the batch key);
    their logs copied into ``logs`` as ``<row>.mcap`` (row = 0…15)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tiny.toml"
        path.write_text(campaign("tiny", 4, 4))
        cli = [sys.executable, "-m", "labrunner", "run", str(path), "--out", str(Path(tmp) / "tiny"), "--workers", "1"]
        subprocess.run(cli, check=True, capture_output=True)
        with Ledger.open_readonly(Path(tmp) / "tiny") as ledger:
            cols = ", ".join((*ROW_COLUMNS, "batch_key", "log_path"))
            rows = [tuple(r) for r in ledger.db.execute(f"SELECT {cols} FROM points ORDER BY seq")]
        for k, row in enumerate(rows):
            if row[-1]:
                shutil.copyfile(Path(tmp) / "tiny" / row[-1], logs / f"{k}.mcap")
        return [row[:-1] for row in rows]


def make(work: Path, name: str, n_gamma: int, n_kp: int, *, finished: float = 1.0) -> Path:
    """Write ``work/name.toml`` and the synthetic campaign directory ``work/name``; return it."""
    file = work / f"{name}.toml"
    file.write_text(campaign(name, n_gamma, n_kp))
    c = spec.load(file)
    directory = work / name
    directory.mkdir()
    runs = directory / "runs"
    runs.mkdir()
    rows = template_rows(runs)
    n = c.grid.size
    meta = {
        "campaign": c.name,
        "campaign_file": c.source,
        "campaign_path": str(file.resolve()),
        "plan_checksum": "synthetic: not planned",
        **plan_inputs.stamp(c),
        "points": str(n),
        "rig": c.rig,
        REAL_RIG: "0" if c.rig_info.simulated else "1",
        "created_at": repr(time.time()),
        "created_by": f"benchmarks/synthetic_ledger.py on {socket.gethostname()}",
    }
    batch = rows[0][-1]
    points = ((seq, point_id(c.name, p), p, batch) for seq, p in enumerate(c.grid.points()))
    with Ledger.create(directory, meta=meta, points=points) as ledger:
        done = int(n * finished)
        now = time.time()
        sets = ", ".join(f"{k} = ?" for k in ROW_COLUMNS)
        ledger.db.execute("BEGIN")
        ledger.db.executemany(
            f"UPDATE points SET {sets}, attempts = 1, host = 'h', pid = 1, claimed_at = ?, finished_at = ? WHERE seq = ?",
            ((*row[:-1], now, now, seq) for seq, row in zip(range(done), itertools.cycle(rows))),
        )
        ledger.db.execute("COMMIT")
        _link_logs(ledger, runs, len(rows))
        seal.seal(ledger)  # as a session of ``run`` that ended cleanly
    (directory / CAMPAIGN_COPY).write_text(c.source)
    return directory


def _link_logs(ledger: Ledger, runs: Path, k: int) -> None:
    """Publish template log ``seq mod k`` as each finished point's log (the first of each, moved;
    the others, hard links) and record its fingerprint (after the last link: a link sets ctime)."""
    first: dict[int, Path] = {}
    for seq, pid in ledger.db.execute("SELECT seq, id FROM points WHERE finished_at IS NOT NULL ORDER BY seq"):
        template, path = runs / f"{seq % k}.mcap", runs / f"{pid}.mcap"
        if seq % k in first:
            os.link(first[seq % k], path)
        elif template.exists():
            first[seq % k] = template.replace(path)
    for j in range(k):  # templates no finished point took
        (runs / f"{j}.mcap").unlink(missing_ok=True)
    sets = ", ".join(f"{c} = ?" for c in FINGERPRINT_COLUMNS)
    ledger.db.execute("BEGIN")
    for j, path in first.items():
        ledger.db.execute(
            f"UPDATE points SET log_path = 'runs/' || id || '.mcap', {sets} WHERE seq % ? = ? AND finished_at IS NOT NULL",
            (*fingerprint(path), k, j),
        )
    ledger.db.execute("COMMIT")


def restamp(directory: Path) -> None:
    """Write the current plan-inputs digest into the ledger (after labrunner's code changed)."""
    with Ledger.open(directory, verify=False) as ledger:
        meta = ledger.meta()
        c = spec.from_text(meta["campaign_file"], source_path=Path(meta["campaign_path"]))
        for key, value in plan_inputs.stamp(c).items():
            ledger.set_meta(key, value)
