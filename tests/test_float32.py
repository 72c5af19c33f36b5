"""float32 devices (docs/control-laws.md, "float32 devices"): the law computed in single precision
(labrunner/rigs/device/doclaw.py with dtype float32, every operation on float32 values) passes
the law check under the a-priori float32 tolerance on every conformance vector, while γ off by
1 % in float32 still fails it; the bound itself holds against exact float32 arithmetic."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from labrunner.rigs.device import description, doclaw, f32bound, lawcheck, vectors
from labrunner.rigs.device.f32bound import Bounded
from labrunner.rigs.registry import load_rig


@functools.cache
def _vector(name: str) -> vectors.Vector:
    """vectors.build of case ``name``, once per case (a pure computation; the tests of each vector
    with the right and the wrong gain, and with float32 and float64, read the same one)."""
    vector = vectors.build(vectors.CASES[name])
    vector.rows.flags.writeable = False
    return vector


def _law_check(name: str, dtype, arithmetic: str, key: str = "gamma", factor: float = 1.0) -> lawcheck.LawCheck:
    """The float32 (``dtype``) document law on vector ``name``'s table, checked as conform checks it."""
    case = vectors.CASES[name]
    vector = _vector(name)
    info = load_rig(case.rig).info
    d = description.decode(vector.data)
    if key in d.law:
        d.law[key] = d.law[key] * factor
    rows, verdict = doclaw.run(d, [s.name for s in info.inputs], [s.name for s in info.outputs], dtype=dtype)
    rows = rows.astype(np.float32).astype(float)  # as logged
    from labrunner.rigs.device.host import to_result

    outcome = to_result(case.point, info, case.fs, _verdict(verdict, len(rows)), rows, {}).outcome
    y = vector.rows[:, [vector.columns.index(s.name) for s in info.outputs]]
    return lawcheck.check(
        case.point, info, rows, outcome, fs=case.fs, duration=case.duration, seed=case.seed,
        rig_safety=vectors.rig_safety(case), measured=y, arithmetic=arithmetic,
    )  # fmt: skip


def _verdict(v: dict, n: int):
    from labrunner.rigs.device import blocks

    return blocks.Verdict(
        v["status"], n, n, 0, str(v.get("monitor", "")),
        *(float(v.get(k, float("nan"))) for k in ("time", "value", "threshold")),
    )  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("name", list(vectors.CASES))
def test_a_float32_device_passes_every_vector_under_the_float32_tolerance(name):
    law = _law_check(name, np.float32, lawcheck.FLOAT32)
    assert law.ok, law.detail
    assert law.arithmetic == "float32"
    assert law.worst_ratio < 1.0


_OFF = [  # the law vectors (a safety vector may trip before the gain shows)
    (n, "gamma") for n, c in vectors.CASES.items() if "gamma" in c.point["controller"] and "safety" not in c.point
    and c.nan_at is None
] + [("plate-mbc", "c_p")]  # fmt: skip


@pytest.mark.slow
@pytest.mark.parametrize("name, key", _OFF)
def test_a_gain_one_percent_off_in_float32_still_fails(name, key):
    """γ (c_p for the plate's model-based law, which has no γ) × 1.01 in a float32 law."""
    law = _law_check(name, np.float32, lawcheck.FLOAT32, key, 1.01)
    assert law.flag.startswith("diverged@tick"), law.detail
    assert "(float32)" in law.detail


def test_the_float64_tolerance_does_not_cover_a_float32_device():
    """Why the arithmetic must be announced: the float64 check flags a correct float32 law."""
    assert not _law_check("mfc1-motor-velocity", np.float32, lawcheck.FLOAT64).ok
    assert _law_check("mfc1-motor-velocity", np.float64, lawcheck.FLOAT64).ok


def test_a_dot_products_bound_holds_for_float32_sums_in_any_order():
    rng = np.random.default_rng(3)
    for _ in range(50):
        w, x = rng.normal(size=200) * 10.0 ** rng.integers(-3, 4), rng.normal(size=200)
        w32, x32 = w.astype(np.float32), x.astype(np.float32)
        bound = f32bound.dot(np.array([Bounded(v) for v in w]), np.array([Bounded(v) for v in x]))
        exact = float(np.dot(w, x))
        assert bound.v == pytest.approx(exact)
        for order in (np.arange(200), np.arange(200)[::-1], rng.permutation(200)):
            s = np.float32(0)
            for j in order:
                s = np.float32(s + w32[j] * x32[j])
            assert abs(float(s) - exact) <= bound.e
        assert bound.e < 1e-3 * np.sum(np.abs(w * x))  # and it is not vacuous


def test_sqrt_near_zero_is_bounded_by_the_square_root_of_the_error():
    q = Bounded(1e-12, 1e-10)  # the float32 value may be anything in [0, 1.01e-10]
    assert q.sqrt().e >= np.sqrt(1.01e-10) - 1e-6
    assert Bounded(4.0, 0.0).sqrt().e == pytest.approx(2.0 * f32bound.U)


def test_the_bound_of_a_non_finite_inputs_vector_prints_no_warning():
    """The plate law's √ of a NaN (the vector's bad input) once made numpy print "invalid value encountered
    in sqrt" under every float32 conform of a plate: a NaN compared in Bounded.sqrt sets the invalid flag."""
    import warnings

    assert all(np.isnan([Bounded(np.nan, 1.0).sqrt().v, Bounded(np.nan, 1.0).sqrt().e]))
    case = vectors.CASES["plate-mfc-non_finite_input"]
    vector = _vector("plate-mfc-non_finite_input")
    info = load_rig(case.rig).info
    y = vector.rows[:, [vector.columns.index(s.name) for s in info.outputs]]
    with warnings.catch_warnings(record=True) as seen:  # recorded: raised, the law's run would catch it
        warnings.simplefilter("always")
        bound = lawcheck.float32_bound(
            case.point, info, y, fs=case.fs, duration=case.duration, seed=case.seed, rig_safety=vectors.rig_safety(case)
        )
    assert [str(w.message) for w in seen] == [] and len(bound) == len(y) and np.isfinite(bound[0]).all()


@pytest.mark.slow
def test_conform_checks_an_emulated_float32_device_under_the_float32_tolerance(tmp_path):
    from tests.test_conform import MOTOR_CASES, _conform
    from tests.test_deviceloop_link import emulator_process, rig_file

    with emulator_process(rig_file("motor-mfc1", "canfd"), ("--float32",)) as config:
        code, report = _conform(tmp_path, config, "--no-protocol")
    assert code == 0, [c for c in report["checks"] if not c["passed"]]
    checks = {c["name"]: c["detail"] for c in report["checks"]}
    assert "laws in float32" in checks["handshake"]
    for case in MOTOR_CASES:
        assert "of the float32 tolerance" in checks[f"vector {case}"]
    with emulator_process(rig_file("motor-mfc1", "canfd"), ("--float32", "--fault-law", "gamma=1.01")) as config:
        code, report = _conform(tmp_path, config, "--no-protocol")
    failed = {c["name"] for c in report["checks"] if not c["passed"]}
    assert code == 1 and failed == {f"vector {c}" for c in MOTOR_CASES if not c.startswith("open-loop")}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["motor-mfc2", "valve-mfc1"])
def test_a_plant_run_on_a_float32_device_passes_its_float32_law_check(name):
    """The closed loop with the twin, the law in float32: the run's law check is ok and says float32."""
    from tests.test_deviceloop_link import device_run, emulator_process, rig_file

    with emulator_process(rig_file(name, "can"), ("--float32",)) as config:
        result = device_run(name, config)
    law = result.diagnostics["law_check"]
    assert law["flag"] == "ok" and law["arithmetic"] == "float32", law
    assert result.outcome.status in ("completed", "aborted")


def test_a_filters_bound_with_its_tail_folded_in_still_bounds_the_full_sum():
    """The FILTER bound keeps N terms of its impulse response and bounds the rest by a geometric
    tail: it must stay above the full sum Σ_j |C A^(k−1−j)| η_j (computed here directly) and not
    far above it."""
    rng = np.random.default_rng(5)
    n, p, m = 3, 1, 1
    Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
    A = Q @ np.diag([0.95, -0.9, 0.8]) @ Q.T  # stable, |A| with a spectral radius above 1
    B, C, D = rng.normal(size=(n, m)), rng.normal(size=(p, n)), rng.normal(size=(p, m))
    M = np.zeros((n + m, p + n))
    M[:n, p:], M[n:, p:], M[:n, :p], M[n:, :p] = A.T, B.T, C.T, D.T
    w = rng.normal(size=400)
    filt = f32bound.FilterBound(np.array([[Bounded(v) for v in row] for row in M]), n, p, np.array([Bounded(w[0])]))
    got = [filt.step(np.array([Bounded(v)]))[0].e for v in w]
    assert filt.tail is not None and len(filt.kernel) < 100  # the tail was folded in
    g = f32bound.gamma(n + m + 1)
    steady = np.linalg.solve(np.eye(n) - A, B)
    x = steady @ w[:1]
    e_x0 = f32bound.U * np.abs(x) + np.abs(steady) @ (f32bound.U * np.abs(w[:1]))
    # |C A^k| for every k, each computed once as before (np.linalg.matrix_power), not once per (k, j)
    # pair: the same values, summed in the same order, so the same reference to the last bit
    gains = [np.abs(C @ np.linalg.matrix_power(A, k)) for k in range(len(w))]
    etas, full = [], []
    for k, v in enumerate(w):
        e_w = f32bound.U * abs(v)
        e = g * (np.abs(C) @ np.abs(x) + np.abs(D) @ [abs(v)]) + np.abs(D) @ [e_w]
        e += gains[k] @ e_x0
        e += sum(gains[k - 1 - j] @ eta for j, eta in enumerate(etas))
        full.append(float(e[0]) + f32bound.U * abs(float((C @ x + D @ [v])[0])))
        etas.append(g * (np.abs(A) @ np.abs(x) + np.abs(B) @ [abs(v)]) + np.abs(B) @ [e_w])
        x = A @ x + B @ [v]
    assert all(a >= b * (1 - 1e-12) for a, b in zip(got, full))
    assert (
        max(a / b for a, b in zip(got, full)) < 5.0
    )  # measured: at most 3.3 (the tail takes max ‖η‖ of all old ticks)


def test_the_shared_reference_is_the_reference_computed_afresh():
    """doclaw computes a trajectory's reference once per tick for every run that shares it; each value and
    bound is what :func:`doclaw.reference` computes on its own."""
    d = description.decode(_vector("plate-mfc-v").data)
    for code, arrays in d.trajectories:
        raw = tuple(a.tobytes() for a in arrays)
        for k in (0, 1, 57, d.ticks - 1):
            for dtype in (Bounded, np.float32):
                shared = doclaw._shared_reference(code, raw, k, d.fs, dtype)
                fresh = doclaw.reference(code, arrays, k, d.fs, doclaw._Arith(dtype))
                assert [(float(a), f32bound.errors([a])[0]) for a in shared] == [
                    (float(b), f32bound.errors([b])[0]) for b in fresh
                ]


def test_a_table_reference_is_computed_afresh_not_looked_up_by_its_bytes():
    """Looking a table up would compare its bytes at every tick (a 100 000-row table: 3.2 MB a tick)."""
    table = np.arange(4.0 * 300)  # 300 rows of (r, ṙ, r̈, r⃛): 9.6 kB, above SHARED_BYTES
    before = doclaw._shared_reference.cache_info().currsize
    at = doclaw._reference_of(4, [np.zeros(1), table], 100.0, doclaw._Arith(np.float64), np.float64)
    assert [float(v) for v in at(7)] == [28.0, 29.0, 30.0, 31.0] and [float(v) for v in at(999)][0] == 1196.0
    assert doclaw._shared_reference.cache_info().currsize == before


def test_a_table_references_row_is_the_row_of_the_whole_table_in_each_arithmetic():
    """reference() converts only tick k's row of a table to the arithmetic (it converted the whole table at
    every tick: O(n²) a run in float32 and Bounded); the values are those of the whole table's row."""
    table = np.random.default_rng(5).normal(size=4 * 50) * 1e3
    for dtype in (np.float64, np.float32, Bounded):
        ar = doclaw._Arith(dtype)
        for k in (0, 1, 49, 50, 500):
            want = list(ar.a(table).reshape(-1, 4)[min(k, 49)])
            got = doclaw.reference(4, [np.zeros(1), table], k, 100.0, ar)
            assert [(float(a), f32bound.errors([a])[0], type(a)) for a in got] == [
                (float(b), f32bound.errors([b])[0], type(b)) for b in want
            ]
