"""MFC laws on ultra-local plants (thesis Sec. 2.2, 2.4), the delayed error dynamics (2.40), the
discrete law (3.3)/(3.4) reconstructed from logged signals, saturation, i_min, and lockstep."""

import math

import numpy as np
import pytest

from labrunner.control import factory
from labrunner.control.mfc import MFC, OutputMap
from labrunner.differentiators import design
from labrunner.rigs.base import RigInfo, Signal

ULTRA = RigInfo("ultra", "test", (Signal("u", "1", -1e6, 1e6),), (Signal("y", "m"),), (1.0, 1e5), 1000.0, (0.0,))
MOTOR = RigInfo(
    "motor", "dcmotor", (Signal("u", "V", -12.0, 12.0),), (Signal("theta", "rad"),), (1.0, 2000.0), 200.0, (0.0,)
)
VALVE = RigInfo(
    "valve", "valve", (Signal("i", "A", 0.0, 1.01),), (Signal("q", "l/min"),), (1.0, 4000.0), 4000.0, (0.0,)
)


def point(kind="mfc1", ctl=None, diff=None, ref=None):
    base_diff = {"alpha": 2, "beta": 2} if diff and "window" in diff else {"alpha": 2, "beta": 2, "omega_c": 100.0}
    return {
        "controller": {"kind": kind, "gamma": 2.0, "k_p": 10.0, **(ctl or {})},
        "differentiator": {**base_diff, **(diff or {})},
        "reference": {"kind": "setpoints", "levels": [0.0, 1.0], "transition": 0.5, "hold": [0.1, 1.0], **(ref or {})},
    }


def simulate(controller, reference, fs, K, *, f, rho, order, y0=None):
    """Closed loop on y⁽ⁿ⁾ = f + ρ·u (exact zero-order-hold step); returns logs of u, y, controlled, f̂."""
    B = controller.batch
    t = np.arange(K) / fs
    R = reference.evaluate(t)
    y = np.zeros((B, 1)) if y0 is None else np.array(y0, float).reshape(B, 1)
    v = np.zeros((B, 1))
    controller.reset(y)
    logs = {k: np.zeros((K, B)) for k in ("u", "y", "c", "f_hat", "e_hat")}
    ts = 1.0 / fs
    for k in range(K):
        u = controller.step(y, R[k])
        logs["u"][k], logs["y"][k], logs["c"][k] = u[:, 0], y[:, 0], controller.controlled[:, 0]
        logs["f_hat"][k], logs["e_hat"][k] = controller.estimates["f_hat"][:, 0], controller.estimates["e_hat"][:, 0]
        acc = f + rho * u
        if order == 1:
            y = y + ts * acc
        else:
            y, v = y + ts * v + ts**2 / 2 * acc, v + ts * acc
    return logs, R


@pytest.mark.parametrize("gamma", [3.0, 6.0, 12.0])
def test_first_order_steady_state_error_vanishes_with_constant_f(gamma):
    """ẏ = f + ρu, f = −4 constant: f̂ acts as integral action, e → 0 for γ = ρ and γ ≠ ρ."""
    fs, rho = 1000.0, 3.0
    c, ref = factory.build([point(ctl={"gamma": gamma, "k_p": 20.0})], ULTRA, fs)
    logs, R = simulate(c, ref, fs, 3000, f=-4.0, rho=rho, order=1)
    e = logs["y"][:, 0] - R[:, 0, 0, 0]
    assert abs(e[-1]) < 1e-6
    assert logs["f_hat"][-1, 0] == pytest.approx(-4.0 * gamma / rho, rel=1e-6)  # f̂ → (γ/ρ) f (thesis 2.39)


def test_second_order_steady_state_error_vanishes_with_constant_f():
    """ÿ = f + ρu with the analytic discretisation (as the thesis uses for the angle, Sec. 3.4.2)."""
    fs, rho = 1000.0, 1.0
    p = point("mfc2", ctl={"gamma": 1.0, "k_p": 100.0, "k_d": 20.0},
              diff={"alpha": 4, "beta": 4, "omega_c": 150.0, "method": "analytic"})  # fmt: skip
    c, ref = factory.build([p], ULTRA, fs)
    logs, R = simulate(c, ref, fs, 4000, f=9.81, rho=rho, order=2)
    e = logs["y"][:, 0] - R[:, 0, 0, 0]
    assert abs(e[-1]) < 1e-6 and np.abs(e).max() < 0.2


def test_midpoint_second_derivative_leaves_the_predicted_offset():
    """Mid-point weights of g̈ do not sum to zero (the low-frequency discretisation error of thesis
    Fig. 3.6 / paper 2 Fig. 5), so a constant output biases f̂ by y·Σŵ₂ and the steady state has
    k_p·e = −Σŵ₂·y, i.e. e = −Σŵ₂·y_r/(k_p + Σŵ₂)."""
    fs, rho, k_p = 1000.0, 1.0, 100.0
    p = point("mfc2", ctl={"gamma": 1.0, "k_p": k_p, "k_d": 20.0}, diff={"alpha": 4, "beta": 4, "omega_c": 150.0})
    c, ref = factory.build([p], ULTRA, fs)
    logs, R = simulate(c, ref, fs, 4000, f=9.81, rho=rho, order=2)
    s2 = float(np.sum(factory.differentiators([p], fs, 2)[0].weights(2)))
    assert abs(s2) > 1e-3
    assert logs["y"][-1, 0] - 1.0 == pytest.approx(-s2 / (k_p + s2), rel=1e-6)


def dde_method_of_steps(t: np.ndarray, e0: float, k_p: float, delay: float) -> np.ndarray:
    """ė(t) = −k_p e(t − δ), e = 0 before 0, e(0) = e0: by the method of steps,
    e(t) = e0 Σ_{n=0}^{⌊t/δ⌋} (−k_p (t − nδ))ⁿ / n!."""
    out = np.zeros_like(t)
    for i, ti in enumerate(t):
        out[i] = e0 * sum((-k_p * (ti - n * delay)) ** n / math.factorial(n) for n in range(int(ti // delay) + 1))
    return out


@pytest.mark.parametrize("k_p", [15.0, 40.0])
def test_error_follows_the_delayed_ode_when_gamma_equals_rho(k_p):
    """Thesis (2.40) with γ = ρ: ė + k_p·e(t − δ_t) ≈ 0. Constant f, stationary start, error step e0."""
    fs, rho, f = 10000.0, 5.0, 2.0
    d = design(alpha=5, beta=5, fs=fs, window=0.02)
    c = MFC(
        [d], 1, gamma=np.array([rho]), k_p=np.array([k_p]), k_d=None, u_min=[[-1e9]], u_max=[[1e9]],
        output=OutputMap("y", 0), u_init=np.array([[-f / rho]]),
    )  # fmt: skip
    ref = factory.reference([{"reference": {"kind": "setpoints", "levels": [1.0], "transition": 1.0, "hold": 1.0}}])
    K = 3000
    logs, R = simulate(c, ref, fs, K, f=f, rho=rho, order=1)
    e = logs["y"][:, 0] - 1.0
    expected = dde_method_of_steps(np.arange(K) / fs, -1.0, k_p, d.delay_s)
    # ê is a distributed delay (kernel g, centroid δ_t, spread σ_g) rather than a pure one. Near
    # t = δ_t the two differ by at most k_p·E[(δ_t − σ)⁺] ≤ k_p·σ_g/2 (first order); once a
    # whole window has passed, the first-order terms cancel (the centroid is δ_t) and
    # O((k_p·σ_g)²) remains.
    sigma_g = d.window_s * math.sqrt(36 / (144 * 13))  # standard deviation of the Beta(6, 6) kernel
    t = np.arange(K) / fs
    assert np.abs(e - expected).max() < k_p * sigma_g / 2 + (k_p * sigma_g) ** 2
    assert np.abs(e - expected)[t >= 2 * d.window_s].max() < (k_p * sigma_g) ** 2
    assert np.abs(expected).max() == pytest.approx(1.0)


def test_difference_quotient_output_and_reference_delay():
    """Motor velocity: Ω[k] = (θ[k] − θ[k−1])·f_s (thesis 2.34); delay = true delays Ω_r by δ."""
    fs = 200.0
    p = point(ctl={"output": "velocity", "gamma": 108.55, "k_p": 50.0}, diff={"alpha": 9, "beta": 9, "omega_c": 200.0},
              ref={"levels": [0.0, 20.0, 0.0], "transition": 1.0, "hold": 1.0, "delay": True})  # fmt: skip
    c, ref = factory.build([p], MOTOR, fs)
    assert c.output_names == ("omega",)
    d = factory.differentiators([p], fs, 1)[0]
    t = np.arange(1000) / fs
    undelayed = factory.reference([{**p, "reference": {**p["reference"], "delay": False}}]).evaluate(
        t - d.discrete_delay_s(0)
    )
    np.testing.assert_allclose(
        ref.evaluate(t)[t >= d.discrete_delay_s(0)], undelayed[t >= d.discrete_delay_s(0)], atol=1e-9
    )
    theta = np.cumsum(np.random.default_rng(0).normal(size=50)) * 0.01
    c.reset(theta[:1, None])
    r = np.zeros((1, 1, 4))
    for k in range(1, 50):
        c.step(theta[k : k + 1, None], r)
        assert c.controlled[0, 0] == pytest.approx((theta[k] - theta[k - 1]) * fs, abs=1e-12)


@pytest.mark.parametrize("kind, extra", [("mfc1", {}), ("mfc1-ff", {}), ("mfc2", {"k_d": 30.0})])
def test_discrete_law_reconstructed_from_logs_with_saturation(kind, extra):
    """u[k] = sat((ẏ_r − k_p ê − f̂)/γ) with f̂[k] = Σ ŵ_n y[k−1−j] − γ Σ ŵ_0 u_sat[k−1−j]
    (thesis 3.3/3.4, paper 2 eq. 25), recomputed from the logged y and the *saturated* u."""
    fs, order = 1000.0, 2 if kind == "mfc2" else 1
    ctl = {"gamma": 0.5, "k_p": 400.0, "u_min": -3.0, "u_max": 2.0, **extra}
    p = point(kind, ctl=ctl, diff={"alpha": 3, "beta": 3, "omega_c": 300.0})
    if kind == "mfc1-ff":  # Polack's feed-forward tuning law: k_p = 0 and no k_p key
        del p["controller"]["k_p"]
    c, ref = factory.build([p], ULTRA, fs)
    K = 1200
    logs, R = simulate(c, ref, fs, K, f=1.0, rho=1.5, order=order)
    u, y = logs["u"][:, 0], logs["y"][:, 0]
    assert u.max() == pytest.approx(2.0) and u.min() >= -3.0  # the limits are reached and kept
    d = factory.differentiators([p], fs, order)[0]
    wn, w0, w1 = d.weights(order), d.weights(0), d.weights(1)
    n = d.n_s
    y_h = np.concatenate([np.full(n + 1, y[0]), y])
    u_h = np.concatenate([np.zeros(n + 1), u])
    e_h = np.concatenate([np.zeros(n + 1), y - R[:, 0, 0, 0]])
    k_p = 0.0 if kind == "mfc1-ff" else ctl["k_p"]
    for k in range(K):
        now = n + 1 + k - np.arange(n)
        f_hat = np.dot(wn, y_h[now - 1]) - 0.5 * np.dot(w0, u_h[now - 1])
        law = R[k, 0, 0, order] - k_p * np.dot(w0, e_h[now]) - f_hat
        if order == 2:
            law -= extra["k_d"] * np.dot(w1, e_h[now])
        assert logs["f_hat"][k, 0] == pytest.approx(f_hat, abs=1e-8 * max(1.0, abs(f_hat)))
        assert u[k] == pytest.approx(min(max(law / 0.5, -3.0), 2.0), abs=1e-8 * max(1.0, abs(law)))


def test_valve_minimal_current():
    """Paper 1 Sec. 4.4.3/4.4.4: i ∈ [i_min, i_max], and i = i_min where the desired flow is zero."""
    fs = 4000.0
    p = point(ctl={"output": "flow", "gamma": 0.4, "k_p": 30.0, "i_min": 0.5}, diff={"omega_c": 250.0},
              ref={"levels": [1.0, 5.0, 0.0], "transition": 0.05, "hold": 0.05})  # fmt: skip
    c, ref = factory.build([p], VALVE, fs)
    R = ref.evaluate(np.arange(800) / fs)
    c.reset(np.zeros((1, 1)))
    q = 0.0
    for k in range(800):
        u = c.step(np.array([[q]]), R[k])
        assert 0.5 <= u[0, 0] <= 1.01
        if R[k, 0, 0, 0] <= 0.0:
            assert u[0, 0] == 0.5
        q += (20.0 * (u[0, 0] - 0.5) - q) / fs * 50.0  # a crude first-order valve


def test_batch_equals_separate_runs():
    """B points with different γ, k_p, k_d and differentiator designs (zero-padded taps) in one
    batch give the same inputs as B separate B = 1 runs, to 1e-12."""
    fs = 1000.0
    points = [
        point("mfc2", {"gamma": 1.0, "k_p": 100.0, "k_d": 20.0}, {"alpha": 2, "beta": 2, "omega_c": 150.0}),
        point(
            "mfc2",
            {"gamma": 2.0, "k_p": 50.0, "k_d": 10.0},
            {"alpha": 5, "beta": 5, "omega_c": 80.0, "method": "analytic"},
        ),
        point(
            "mfc2", {"gamma": 0.7, "k_p": 300.0, "k_d": 35.0, "u_max": 30.0}, {"alpha": 3, "beta": 4, "window": 0.031}
        ),
        point(
            "mfc2",
            {"gamma": 1.3, "k_p": 10.0, "k_d": 5.0, "filter": "output"},
            {"alpha": 2.5, "beta": 2.5, "N": 1, "omega_c": 200.0},
        ),
    ]
    c, ref = factory.build(points, ULTRA, fs)
    logs, _ = simulate(c, ref, fs, 1500, f=-3.0, rho=1.0, order=2)
    for i, p in enumerate(points):
        ci, refi = factory.build([p], ULTRA, fs)
        single, _ = simulate(ci, refi, fs, 1500, f=-3.0, rho=1.0, order=2)
        np.testing.assert_allclose(logs["u"][:, i], single["u"][:, 0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(logs["f_hat"][:, i], single["f_hat"][:, 0], rtol=0, atol=1e-12)


def test_shared_design_layout_equals_per_row_bank():
    """A large batch sharing one design uses one FIR per tap vector (a BLAS product); it matches
    the per-row bank of the B = 1 runs to 1e-12 of each signal's scale."""
    fs, B = 1000.0, 40
    points = [
        point(
            "mfc2",
            {"gamma": 0.5 + 0.05 * i, "k_p": 50.0 + 5 * i, "k_d": 10.0 + i},
            {"alpha": 3, "beta": 3, "omega_c": 120.0},
        )
        for i in range(B)
    ]
    c, ref = factory.build(points, ULTRA, fs)
    assert c.estimator._shared
    logs, _ = simulate(c, ref, fs, 800, f=2.0, rho=1.0, order=2)
    for i in (0, 17, B - 1):
        ci, refi = factory.build([points[i]], ULTRA, fs)
        assert not ci.estimator._shared
        single, _ = simulate(ci, refi, fs, 800, f=2.0, rho=1.0, order=2)
        # BLAS and einsum sum in different orders: equal to 1e-12 relative to the signal's scale
        for name in ("u", "e_hat", "f_hat"):
            scale = np.abs(single[name][:, 0]).max()
            np.testing.assert_allclose(logs[name][:, i], single[name][:, 0], rtol=0, atol=1e-12 * scale)
