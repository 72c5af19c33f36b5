"""Method-of-steps simulations of the delayed error equations (thesis (2.40), (2.45), (2.52), (2.57),
(A.18)) written out from the thesis, independent of labrunner's quasi-polynomials: a solution
decays 2 % inside each closed-form boundary and grows 2 % outside it."""

from __future__ import annotations

import numpy as np

from labrunner.stability import bounds, case_quasipolynomial, stable_intervals

A, B = 39.44, 108.55
DELAY = 0.035
STEPS_PER_DELAY = 16
HORIZON = 600  # delays


def error_matrices(case: str, kw: dict, k_p: float, k_d: float | None) -> tuple[np.ndarray, np.ndarray]:
    """x = (e, ė): x'(t) = A0 x(t) + A1 x(t − δ), the error equations as printed in the thesis."""
    r = (kw.get("rho") or kw.get("b")) / kw["gamma"]
    a0m, a1m = np.zeros((2, 2)), np.zeros((2, 2))
    if case == "mfc1-ultralocal":  # (2.40)
        a1m[0, 0] = -r * k_p
    elif case == "mfc1-motor":  # (2.45)
        a0m[0, 0], a1m[0, 0] = -kw["a"], -r * (k_p - kw["a"])
    else:  # (2.52), (2.57), (A.18)
        p0, p1 = (kw.get("a0", 0.0), kw.get("a1", kw.get("a", 0.0)))
        a0m[0, 1] = 1.0
        a0m[1] = [-p0, -p1]
        a1m[1] = [-r * (k_p - p0), -r * (k_d - p1)]
    return a0m, a1m


def grows(a0m: np.ndarray, a1m: np.ndarray, a2m: np.ndarray | None = None) -> np.ndarray:
    """RK4 with step δ/M over a batch (B, 2, 2) of x'(t) = A0 x(t) + A1 x(t − δ) + A2 x'(t − δ)
    (A2: the neutral term of (A.11), zero if not given); delayed states at half steps by cubic
    Hermite interpolation of the stored solution, delayed derivatives by cubic Lagrange
    interpolation of the stored ones. History e = 1, ė = 0 on [−δ, 0]. True where the envelope of
    e over the last 10 % of the horizon exceeds the one at 25-35 %."""
    m, n_steps = STEPS_PER_DELAY, HORIZON * STEPS_PER_DELAY
    h = DELAY / m
    batch = a0m.shape[0]
    a2m = np.zeros_like(a0m) if a2m is None else a2m
    x = np.zeros((n_steps + m + 1, batch, 2))
    f = np.zeros_like(x)  # x' (0 on the constant history)
    x[: m + 1, :, 0] = 1.0  # history on [−δ, 0] at indices 0..m

    def rhs(now, late, late_rate):
        return sum(np.einsum("bij,bj->bi", mat, v) for mat, v in ((a0m, now), (a1m, late), (a2m, late_rate)))

    f[m] = rhs(x[m], x[0], f[0])
    for k in range(m, n_steps + m):
        late0, late1 = x[k - m], x[k - m + 1]
        late_mid = 0.5 * (late0 + late1) + h * (f[k - m] - f[k - m + 1]) / 8.0
        rate_mid = (9.0 * (f[k - m] + f[k - m + 1]) - f[max(k - m - 1, 0)] - f[k - m + 2]) / 16.0
        k1 = f[k]
        k2 = rhs(x[k] + 0.5 * h * k1, late_mid, rate_mid)
        k3 = rhs(x[k] + 0.5 * h * k2, late_mid, rate_mid)
        k4 = rhs(x[k] + h * k3, late1, f[k - m + 1])
        x[k + 1] = x[k] + h * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        f[k + 1] = rhs(x[k + 1], x[k + 1 - m], f[k + 1 - m])
    e = np.abs(x[m:, :, 0])
    early = e[int(0.25 * n_steps) : int(0.35 * n_steps)].max(axis=0)
    late = e[int(0.9 * n_steps) :].max(axis=0)
    return late > early


def boundary_points(case: str, kw: dict) -> list[tuple[float, float | None, bool]]:
    """(k_p, k_d, stable?) 2 % inside and outside each boundary; 2 % of the interval's width for
    a bound at 0. k_d boundaries at the middle of the k_p interval 2 % inside."""

    def nudge(edge, inward, width):
        step = 0.02 * max(abs(edge), width)
        return edge + inward * step, edge - inward * step

    out = []
    if case.startswith("mfc1"):
        lo, hi = bounds(case, delay=DELAY, **kw)["k_p"]
        for edge, inward in ((lo, 1), (hi, -1)):
            inside, outside = nudge(edge, inward, hi - lo)
            out += [(inside, None, True), (outside, None, False)]
        return out
    kd_lo, kd_hi = bounds(case, delay=DELAY, k_d=0.0, **kw)["k_d"]
    kd_mid = 0.5 * (kd_lo + kd_hi)
    lo, hi = bounds(case, delay=DELAY, k_d=kd_mid, **kw)["k_p"]
    for edge, inward in ((lo, 1), (hi, -1)):
        inside, outside = nudge(edge, inward, hi - lo)
        out += [(inside, kd_mid, True), (outside, kd_mid, False)]
    for edge, inward in ((kd_lo, 1), (kd_hi, -1)):
        inside, outside = nudge(edge, inward, kd_hi - kd_lo)
        k_p = float(np.mean(bounds(case, delay=DELAY, k_d=inside, **kw)["k_p"]))
        out += [(k_p, inside, True), (k_p, outside, False)]
    return out


SETUPS = [
    ("mfc1-ultralocal", {"gamma": B, "rho": B}),
    ("mfc1-motor", {"gamma": 0.9 * B, "a": A, "b": B}),
    ("mfc1-motor", {"gamma": 1.1 * B, "a": -20.0, "b": B}),  # remark 2.8: unstable plant
    ("mfc2-ultralocal", {"gamma": B, "rho": B}),
    ("mfc2-motor", {"gamma": 1.1 * B, "a": A, "b": B}),
    ("mfc2-second-order", {"gamma": B, "a0": 300.0, "a1": A, "b": B}),
]


def test_simulations_decay_inside_and_grow_outside_every_boundary():
    labels, mats0, mats1, expected = [], [], [], []
    for case, kw in SETUPS:
        for k_p, k_d, stable in boundary_points(case, kw):
            m0, m1 = error_matrices(case, kw, k_p, k_d)
            labels.append(f"{case} k_p={k_p:.4g} k_d={k_d}")
            mats0.append(m0)
            mats1.append(m1)
            expected.append(not stable)
    assert len(labels) == 3 * 4 + 3 * 8
    got = grows(np.array(mats0), np.array(mats1))
    wrong = [lab for lab, g, e in zip(labels, got, expected) if g != e]
    assert not wrong, wrong


def test_simulations_grow_in_the_gap_left_by_2_53():
    # k_d between the correct (π/2)γ/(ρδ) and the printed (γ/(δρ)) z̃ sin z̃: every k_p grows
    kw = {"gamma": B, "rho": B}
    z = 2.028757838110434
    k_d = 0.5 * (np.pi / 2 + z * np.sin(z)) / DELAY
    k_ps = np.array([0.01, 0.1, 0.3, 1.0, 3.0]) / DELAY**2
    mats = [error_matrices("mfc2-ultralocal", kw, k_p, k_d) for k_p in k_ps]
    assert np.all(grows(np.array([m[0] for m in mats]), np.array([m[1] for m in mats])))


def test_neutral_a11_decays_inside_and_grows_outside_the_solver_boundaries():
    """(A.11), the motor loop without approximation (2.43a), has no closed form: its k_p boundaries
    come from the neutral spectral abscissa alone, and the method of steps confirms them (±2 %)."""
    mats, expected, labels = [], [], []
    for gamma in (0.7 * B, 1.1 * B):

        def family(k_p, gamma=gamma):
            return case_quasipolynomial("mfc1-motor", gamma=gamma, delay=DELAY, a=A, b=B, k_p=k_p, neutral=True)

        ((lo, hi),) = stable_intervals(family, -50.0, 400.0, n_scan=81)
        neutral = (gamma - B) / gamma  # coefficient of ė(t − δ) in (A.11)
        for edge, inward in ((lo, 1), (hi, -1)):
            step = 0.02 * max(abs(edge), hi - lo)
            for k_p, stable in ((edge + inward * step, True), (edge - inward * step, False)):
                a0m, a1m, a2m = np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2))
                a0m[0, 0] = -A
                a1m[0, 0] = -(B / gamma * (k_p - A) - neutral * A)
                a2m[0, 0] = neutral
                mats.append((a0m, a1m, a2m))
                expected.append(not stable)
                labels.append(f"gamma={gamma / B:.1f}b k_p={k_p:.4g}")
    got = grows(*(np.array([m[i] for m in mats]) for i in range(3)))
    wrong = [lab for lab, g, e in zip(labels, got, expected) if g != e]
    assert not wrong, wrong
