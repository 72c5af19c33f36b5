"""Coverage of the conformance vectors (docs/control-laws.md, "Coverage"): every law feature and
safety monitor is exercised, for every rig kind that has it, by the vectors the table names — each
named vector is checked to exercise it (read from its files, not from its name), and an n/a cell
to have none — and a motor firmware that saturates after feeding its estimators, or ignores the
description's SATURATION, fails a motor vector."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from labrunner.rigs.device import description, doclaw, lawcheck, vectors
from labrunner.rigs.device.host import to_result
from labrunner.rigs.registry import load_rig

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "docs" / "vectors"
KINDS = ("dcmotor", "valve", "plate")
TRAJECTORY = {1: "reference setpoints", 2: "reference steps", 3: "reference sine", 4: "reference table"}


def features(folder: Path) -> set[str]:
    """What one shipped vector exercises, from its description, rows and verdict."""
    d = description.decode((folder / "description.bin").read_bytes())
    header = (folder / "vector.csv").read_text().splitlines()[0].split(",")[1:]
    rows = np.loadtxt(folder / "vector.csv", delimiter=",", skiprows=1, ndmin=2)[:, 1:]
    verdict = dict(line.split(" = ", 1) for line in (folder / "verdict.txt").read_text().splitlines())
    found = {TRAJECTORY[code] for code, _ in d.trajectories}
    u = rows[:, : d.n_inputs]
    refs = rows[:, [j for j, name in enumerate(header) if name.startswith("ref_")]]
    applies = np.ones(len(rows), bool) if "i_min" not in d.law else refs[:, 0] > 0  # r ≤ 0: i_min, not a clamp
    if d.kind != "open-loop":
        if np.any((u == d.saturation[0]) & applies[:, None]):
            found.add("saturation at u_min")
        if np.any(u == d.saturation[1]):
            found.add("saturation at u_max")
    if "i_min" in d.law and np.any(refs[:, 0] <= 0):
        found.add("i_min")
    monitor = verdict["monitor"]
    if verdict["status"] == "aborted":
        base, _, signal = monitor.partition(":")
        found.add(f"{base} (derived)" if signal.startswith("h") else base)
    if verdict["status"] == "no-motion":
        found.add(f"no-motion rule {d.motion[1]}")
    return found


def rig_kind(folder: Path) -> str:
    return load_rig(vectors.CASES[folder.name].rig).info.kind


def documented() -> dict[str, dict[str, set[str] | None]]:
    """The coverage table of docs/control-laws.md: feature → rig kind → vectors (None: n/a)."""
    text = (ROOT / "docs" / "control-laws.md").read_text()
    lines = text.split("<!-- coverage -->")[1].strip().splitlines()
    table = lines[: next((i for i, line in enumerate(lines) if not line.startswith("|")), len(lines))]
    out: dict[str, dict[str, set[str] | None]] = {}
    for line in table[2:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        out[cells[0].strip("`")] = {
            kind: None if cell.startswith("n/a") else set(re.findall(r"`([^`]+)`", cell))
            for kind, cell in zip(KINDS, cells[1:])
        }
    return out


def test_the_coverage_table_is_what_the_shipped_vectors_exercise():
    seen: dict[str, dict[str, set[str]]] = {}
    for folder in sorted(p for p in SHIPPED.iterdir() if p.is_dir()):
        for feature in features(folder):
            seen.setdefault(feature, {k: set() for k in KINDS})[rig_kind(folder)].add(folder.name)
    table = documented()
    assert set(table) == set(seen), set(table) ^ set(seen)
    for feature, kinds in table.items():
        for kind, names in kinds.items():
            if names is None:
                assert not seen[feature][kind], f"{feature} / {kind} is n/a but {seen[feature][kind]} exercise it"
            else:  # the table names some of the vectors that do (a feature every plate vector has: a few)
                assert names and names <= seen[feature][kind], f"{feature} / {kind}: {names - seen[feature][kind]}"


def _check(name: str, law) -> lawcheck.LawCheck:
    """The law check of a firmware whose law is ``law`` on vector ``name`` (as conform checks it)."""
    case = vectors.CASES[name]
    vector = vectors.build(case)
    info = load_rig(case.rig).info
    d = description.decode(vector.data)
    rows, v = law(d, [s.name for s in info.inputs], [s.name for s in info.outputs])
    rows = rows.astype(np.float32).astype(float)
    from tests.test_float32 import _verdict

    outcome = to_result(case.point, info, case.fs, _verdict(v, len(rows)), rows, {}).outcome
    y = vector.rows[:, [vector.columns.index(s.name) for s in info.outputs]]
    return lawcheck.check(
        case.point, info, rows, outcome, fs=case.fs, duration=case.duration, seed=case.seed,
        rig_safety=vectors.rig_safety(case), measured=y,
    )  # fmt: skip


def _estimators_fed_unsaturated(monkeypatch):
    """A firmware that feeds its estimators u* (the law's input before saturation), not the applied u."""
    law, step = doclaw._law, doclaw.Estimator.step

    def law_keeping_u_star(d, lawc, c, s, y, r, u_prev, ar):
        u, extra, est = law(d, lawc, c, s, y, r, u_prev, ar)
        if "est" in s:
            s["est"].u_star = u[0]  # what its next tick's estimate will use as v[k]
        return u, extra, est

    def step_on_u_star(self, x, v_prev, r):
        return step(self, x, getattr(self, "u_star", v_prev), r)

    monkeypatch.setattr(doclaw, "_law", law_keeping_u_star)
    monkeypatch.setattr(doclaw.Estimator, "step", step_on_u_star)


def _rig_limits_only(d, inputs, outputs):
    """A firmware that clamps to the rig's input range (±12 V), not the description's SATURATION."""
    d = dataclasses.replace(d, saturation=(np.full(d.n_inputs, -12.0), np.full(d.n_inputs, 12.0)))
    return doclaw.run(d, inputs, outputs)


MOTOR = [n for n in vectors.CASES if load_rig(vectors.CASES[n].rig).info.kind == "dcmotor"]


def test_a_motor_firmware_with_the_wrong_saturation_fails_a_motor_vector(monkeypatch):
    assert all(_check(n, doclaw.run).ok for n in ("mfc1-motor-saturation", "mfc1-motor-velocity"))
    assert not _check("mfc1-motor-saturation", _rig_limits_only).ok
    _estimators_fed_unsaturated(monkeypatch)
    wrong = _check("mfc1-motor-saturation", doclaw.run)
    assert wrong.flag.startswith("diverged@tick"), wrong.detail


@pytest.mark.slow
def test_before_the_saturation_vector_no_motor_vector_caught_those_firmwares(monkeypatch):
    """The hole the coverage closes: the other motor vectors never saturate, so both pass them."""
    others = [n for n in MOTOR if n != "mfc1-motor-saturation" and "open-loop" not in n and "non_finite" not in n]
    assert all(_check(n, _rig_limits_only).ok for n in others)
    _estimators_fed_unsaturated(monkeypatch)
    assert all(_check(n, doclaw.run).ok for n in others)
