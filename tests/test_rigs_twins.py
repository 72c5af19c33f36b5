"""Sim twins against analytic behaviour and the papers' numbers (thesis Sec. 2.4.1/3.2, paper 1)."""

from __future__ import annotations

import numpy as np
import pytest
from naive_reference import naive
from scipy.integrate import solve_ivp

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.registry import load_rig
from labrunner.rigs.sim.valve import ValveTwin, static_flow

A, B_GAIN = 39.44, 108.55
DTHETA = 2 * np.pi / 2048


def run(rig, u, seeds=(0,), fs=None, overrides=None):
    """Drive ``rig`` with ``u`` (K,) or (K, B); return the measurements (K + 1, B)."""
    u = np.asarray(u, dtype=float)
    u = u[:, None] if u.ndim == 1 else u
    y0 = rig.reset(len(seeds), seeds, fs or rig.info.fs_default, overrides)
    ys = [y0[:, 0]] + [rig.step(uk[:, None])[:, 0] for uk in np.broadcast_to(u, (u.shape[0], len(seeds)))]
    return np.array(ys)


# -- DC motor ------------------------------------------------------------------------------------
def test_frictionless_step_response_matches_thesis_model():
    """Ω(t) = (b u / a)(1 − e^(−a t)) of (2.31b); θ its integral, quantised by the encoder."""
    rig = load_rig("dcmotor-frictionless")
    fs, u = 200.0, 6.0
    theta = run(rig, np.full(200, u), fs=fs)[:, 0]
    t = np.arange(theta.size) / fs
    exact = B_GAIN * u / A * (t - (1 - np.exp(-A * t)) / A)
    assert np.max(np.abs(theta - exact)) <= DTHETA / 2 + 1e-9
    omega = np.diff(theta) * fs  # difference quotient (2.34), centred at t - t_s/2
    tm = t[1:] - 0.5 / fs
    assert np.max(np.abs(omega - B_GAIN * u / A * (1 - np.exp(-A * tm)))) <= DTHETA * fs + 0.05
    assert omega[-1] == pytest.approx(B_GAIN * u / A, abs=DTHETA * fs)


def test_ideal_encoder_gives_exact_discretisation():
    rig = load_rig("dcmotor-frictionless")
    theta = run(rig, np.full(100, -3.0), fs=200.0, overrides={"encoder_counts": 0})[:, 0]
    t = np.arange(theta.size) / 200.0
    np.testing.assert_allclose(theta, -3 * B_GAIN / A * (t - (1 - np.exp(-A * t)) / A), atol=1e-10)


def test_electrical_lag_matches_ode_solver():
    """With L/R > 0 the twin integrates (2.30)-style dynamics exactly; reference: solve_ivp."""
    tau, fs = 2e-3, 100.0
    rig = load_rig("dcmotor-frictionless")
    u = np.where(np.arange(50) < 25, 12.0, -5.0)
    theta = run(rig, u, fs=fs, overrides={"encoder_counts": 0, "electrical_tau": tau})[:, 0]

    def rhs(t, x):
        uk = u[min(int(t * fs + 1e-9), u.size - 1)]
        return [x[1], -A * x[1] + B_GAIN * x[2], (uk - x[2]) / tau]

    ref = [0.0]
    x = [0.0, 0.0, 0.0]
    for k in range(u.size):
        sol = solve_ivp(rhs, (k / fs, (k + 1) / fs), x, rtol=1e-11, atol=1e-12, method="LSODA")
        x = sol.y[:, -1]
        ref.append(x[0])
    np.testing.assert_allclose(theta, ref, atol=1e-7)


def test_small_voltage_does_not_move_default_twin():
    """Thesis Fig. 3.10 'white circles': below the breakaway voltage the load stays at rest."""
    rig = load_rig("dcmotor-sim")
    theta = run(rig, np.full(400, 0.5), seeds=(1, 2, 3))
    assert np.all(theta == 0.0)
    moved = run(rig, np.full(400, 2.0), seeds=(1,))
    assert np.abs(moved[-1, 0]) > 10 * DTHETA


def test_friction_stops_the_load_when_the_input_drops():
    rig = load_rig("dcmotor-sim")
    run(rig, np.r_[np.full(100, 6.0), np.full(100, 0.0)], seeds=(4,))
    assert rig.state["omega"][0] == 0.0


def test_encoder_quantisation_step_is_2pi_over_2048():
    rig = load_rig("dcmotor-frictionless")
    theta = run(rig, np.full(40, 0.05), fs=1000.0)[:, 0]  # a slow creep through a few counts
    counts = theta / DTHETA
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    steps = np.unique(np.round(np.diff(counts)))
    assert set(steps) <= {0.0, 1.0} and 1.0 in steps


def test_backlash_lags_the_load_by_half_the_play_each_way():
    w = 0.04
    rig = load_rig("dcmotor-frictionless")
    u = np.r_[np.full(60, 6.0), np.full(120, -6.0)]
    over = {"encoder_counts": 0, "backlash": np.array([0.0, w])}
    theta = run(rig, np.tile(u[:, None], (1, 2)), seeds=(0, 0), overrides=over)
    forward, backward = theta[55], theta[-1]
    assert forward[1] - forward[0] == pytest.approx(-w / 2, abs=1e-9)
    assert backward[1] - backward[0] == pytest.approx(w / 2, abs=1e-9)


def test_noise_reproducible_per_seed_and_batch_equals_single_runs():
    rig = load_rig("dcmotor-sim")
    u = 3.0 * np.sin(np.arange(300) / 20.0)
    seeds = (11, 12, 13)
    over = {"a": np.array([30.0, 39.44, 50.0]), "input_v": 0.5}
    batch = run(rig, np.tile(u[:, None], (1, 3)), seeds=seeds, overrides=over)
    for i, s in enumerate(seeds):
        single = run(rig, u, seeds=(s,), overrides={"a": over["a"][i], "input_v": 0.5})
        np.testing.assert_array_equal(batch[:, i], single[:, 0])
    again = run(rig, np.tile(u[:, None], (1, 3)), seeds=seeds, overrides=over)
    np.testing.assert_array_equal(batch, again)
    other = run(rig, u, seeds=(14,), overrides={"a": 30.0, "input_v": 0.5})
    assert not np.array_equal(other[:, 0], batch[:, 0])
    # runs with equal seeds (they share a generator), each at its own noise level
    levels = np.array([0.5, 0.2, 0.5])
    shared = run(rig, np.tile(u[:, None], (1, 3)), seeds=(11, 11, 12), overrides={"input_v": levels})
    for i, s in enumerate((11, 11, 12)):
        single = run(rig, u, seeds=(s,), overrides={"input_v": levels[i]})
        np.testing.assert_array_equal(shared[:, i], single[:, 0])


def _motor_reference(rig, u: np.ndarray, seeds, overrides) -> np.ndarray:
    """The motor of benchmarks/naive_reference.py (the integrator written plainly, one run and one
    scalar at a time, its own ZOH matrices) with each run's parameters: the reference of the
    fused, batched sub-step."""
    rig.reset(len(seeds), seeds, 200.0, overrides)
    out = np.empty((u.shape[0] + 1, len(seeds)))
    for i, seed in enumerate(seeds):
        motor = naive.Motor({k: float(v[i]) for k, v in rig.p.items()}, 200.0, seed)
        out[:, i] = [motor.measure()] + [motor.step(float(uk)) for uk in u[:, i]]
    return out


def test_fused_motor_substep_equals_the_plain_reference():
    """Stick, breakaway, reversals, saturation, backlash, no lag / no friction in some runs, noise."""
    rig = load_rig("dcmotor-sim")
    t = np.arange(400) / 200.0
    u = np.stack(
        [
            0.5 + 0 * t,
            3.0 * np.sin(4 * t),
            20.0 * np.sign(np.sin(3 * t)),
            1.2 * np.sin(9 * t),
            6.0 * np.sin(2 * t),
            np.where(t < 1.0, 8.0, 0.0),
        ],
        axis=1,
    )
    seeds = (1, 2, 3, 4, 5, 6)
    over = {
        "electrical_tau": np.array([5e-4, 0.0, 5e-4, 1e-3, 0.0, 5e-4]),
        "coulomb_friction": np.array([0.6, 0.0, 0.3, 0.6, 0.6, 0.0]),
        "static_friction": np.array([0.8, 0.0, 0.8, 1.0, 0.6, 0.8]),
        "backlash": np.array([0.02, 0.0, 0.05, 0.02, 0.02, 0.0]),
        "input_v": np.array([0.02, 0.0, 0.5, 0.02, 0.0, 0.1]),
    }
    fused = run(rig, u, seeds=seeds, overrides=over)
    reference = _motor_reference(rig, u, seeds, over)
    np.testing.assert_array_equal(fused, reference)
    assert len(np.unique(fused[-1])) == 6 and np.any(fused[:, 0] == 0.0)


def test_safe_state_brings_the_motor_to_rest():
    rig = load_rig("dcmotor-sim")
    rig.reset(2, [0, 1], 200.0)
    for _ in range(100):
        rig.step(np.array([[8.0], [8.0]]))
    rig.safe_state(np.array([True, False]))
    for _ in range(100):
        rig.step(np.array([[8.0], [8.0]]))
    assert rig.state["omega"][0] == 0.0 and rig.state["omega"][1] > 20.0
    np.testing.assert_array_equal(rig.applied_input[:, 0], [0.0, 8.0])


def test_motor_constants_for_maps():
    c = load_rig("dcmotor-sim").info.constants
    assert (c["a"], c["b"], c["rho"]) == (A, B_GAIN, B_GAIN)
    assert c["dtheta"] == pytest.approx(DTHETA)


# -- valve -----------------------------------------------------------------------------------------
def test_no_flow_below_the_main_stage_threshold():
    """Paper 1 Sec. 3.3: the main spool opens only above ≈ 50 % of the maximal current."""
    rig = load_rig("valve-sim")
    q = run(rig, np.full(4000, 0.45), seeds=(0, 1))
    assert np.all(q < 0.15) and np.all(rig.state["flow"] < 0.1)
    q_open = run(rig, np.full(4000, 0.6), seeds=(0,))
    assert q_open[-1, 0] > 5.0


def test_static_flow_characteristic_within_hysteresis():
    rig = load_rig("valve-sim")
    p = rig.config.parameters
    for i in (0.56, 0.62, 0.7):
        q = run(rig, np.full(6000, i), seeds=(3,))[-400:, 0].mean()
        lo, hi = static_flow(i - p["hysteresis"] / 2 - 0.004, p), static_flow(i, p)
        assert lo - 0.1 <= q <= hi + 0.1


def test_magnetic_hysteresis_more_flow_on_the_way_down():
    rig = load_rig("valve-sim")
    up_down = np.r_[np.linspace(0.5, 0.7, 8000), np.linspace(0.7, 0.5, 8000)]
    rig.reset(1, [0], 4000.0, {"flow_lpm": 0.0})
    flow = []
    for i in up_down:
        rig.step(np.array([[i]]))
        flow.append(rig.state["flow"][0])
    flow = np.array(flow)
    k_up, k_down = np.argmin(np.abs(up_down[:8000] - 0.6)), 8000 + np.argmin(np.abs(up_down[8000:] - 0.6))
    assert flow[k_down] > flow[k_up] + 0.5


def _settle_then(rig, i_then, overrides):
    """Ramp up to 0.62 A, settle 0.25 s (17 main-spool time constants), then hold ``i_then`` for
    0.25 s; return the change of the main stroke and of the true flow (no noise)."""
    rig.reset(1, [0], 4000.0, {"flow_lpm": 0.0, **overrides})
    for i in np.r_[np.linspace(0.5, 0.62, 1000), np.full(1000, 0.62)]:
        rig.step(np.array([[i]]))
    before = rig.state
    for _ in range(1000):
        rig.step(np.array([[i_then]]))
    return rig.state["main"][0] - before["main"][0], rig.state["flow"][0] - before["flow"][0]


def test_main_spool_friction_gives_lost_motion_on_reversal():
    """Static and Coulomb friction of the main spool (hysteresis off to isolate it): after a rise,
    a small current reversal leaves the spool stuck; a larger one breaks it away and the spool ends
    2·F_c short of the frictionless stroke change Δx_t = Δi / (i_max (1 − p_th))."""
    rig = load_rig("valve-sim")
    p = rig.config.parameters
    fc = p["main_coulomb_friction"]
    per_amp = 1.0 / (p["i_max"] * (1.0 - p["pilot_threshold"]))
    frictionless = {"hysteresis": 0.0, "main_static_friction": 0.0, "main_coulomb_friction": 0.0}
    small, large = -0.003, -0.008  # Δx_t = −0.0059 (inside F_c + F_s = 0.010), −0.0158
    moved, dq = _settle_then(rig, 0.62 + small, {"hysteresis": 0.0})
    assert moved == 0.0 and abs(dq) < 1e-3  # only the pilot stage's tiny flow changes
    assert _settle_then(rig, 0.62 + small, frictionless)[0] == pytest.approx(small * per_amp, rel=1e-6)
    moved, _ = _settle_then(rig, 0.62 + large, {"hysteresis": 0.0})
    assert moved == pytest.approx(large * per_amp + 2 * fc, rel=1e-6)


def test_flow_is_orifice_flow_through_valve_and_return_path():
    """q = G(x)·√Δp_valve with G = K_m x_m + K_p x_p, the valve's drop Δp_valve = p_s − (q/G_d)²
    left by the return path; so at a fixed opening the flow scales with √p_s (30 bar vs 7.5 bar: ×2)."""
    rig = load_rig("valve-sim")
    p = rig.config.parameters
    flows = []
    for supply in (30.0, 7.5):
        rig.reset(1, [0], 4000.0, {"flow_lpm": 0.0, "supply_pressure": supply})
        for _ in range(2000):
            rig.step(np.array([[0.6]]))
        s = rig.state
        g = p["main_conductance"] * s["main"][0] + p["pilot_conductance"] * s["pilot"][0]
        q = s["flow"][0]
        assert 1.0 < q < p["pump_flow"]  # open, below the pump's limit
        assert q == pytest.approx(g * np.sqrt(supply - (q / p["downstream_conductance"]) ** 2), rel=1e-12)
        flows.append(q)
    assert flows[0] / flows[1] == pytest.approx(2.0, rel=1e-9)


def test_flow_sensor_delay_about_50_ms():
    """Paper 1 Sec. 5.4: the sensor shows the flow ≈ 50 ms late."""
    rig = load_rig("valve-sim")
    fs = 4000.0
    rig.reset(1, [0], fs, {"flow_lpm": 0.0})
    true, meas = [], []
    for k in range(2000):
        meas.append(rig.step(np.array([[0.65 if k >= 400 else 0.3]]))[0, 0])
        true.append(rig.state["flow"][0])
    true, meas = np.array(true), np.array(meas)
    level = 0.5 * true[-1]
    delay = (np.argmax(meas > level) - np.argmax(true > level)) / fs
    assert 0.05 <= delay <= 0.06


def test_flow_reading_range_and_noise():
    rig = load_rig("valve-sim")
    q = run(rig, np.full(4000, 1.01), seeds=(5,))
    assert q.max() == 20.0  # the sensor's range ends at 20 l/min; the pump gives 21.9
    assert rig.state["flow"][0] == pytest.approx(rig.config.parameters["pump_flow"])
    q2 = run(rig, np.full(4000, 0.6), seeds=(5, 6))
    assert np.std(q2[-1000:, 0] - q2[-1000:, 1]) == pytest.approx(0.03 * np.sqrt(2), rel=0.15)


def test_valve_batch_equals_single_runs_with_overrides():
    rig = load_rig("valve-sim")
    i = 0.5 + 0.1 * np.sin(np.arange(1500) / 200.0)
    over = {"sensor_delay": np.array([0.05, 0.02]), "hysteresis": np.array([0.02, 0.0])}
    batch = run(rig, np.tile(i[:, None], (1, 2)), seeds=(7, 8), overrides=over)
    for j, s in enumerate((7, 8)):
        single = run(rig, i, seeds=(s,), overrides={k: v[j] for k, v in over.items()})
        np.testing.assert_array_equal(batch[:, j], single[:, 0])


def test_valve_nominal_gain_brackets_paper_gamma():
    """The γ = 0.4 m³/(A s²) of paper 1 Sec. 5.3 lies in the stable band γ ∈ (ρ/2, 10 ρ)."""
    c = load_rig("valve-sim").info.constants
    assert c["rho_si"] == pytest.approx(c["rho"] / 60_000)
    assert c["rho_si"] / 2 < 0.4 < 10 * c["rho_si"]
    assert c["q_sensor_min"] == 1.2 and c["sensor_delay"] == 0.05


def _mfc_valve(gamma: np.ndarray, k_p: np.ndarray, fs: float = 4000.0):
    """Paper 1 eq. (16) with differentiator No. 1 of Table 1 (α = β = 2, ω_c = 250 rad/s)."""
    from labrunner.differentiators import design

    d = design(alpha=2, beta=2, fs=fs, omega_c=250.0)
    w0, w1 = d.weights(0), d.weights(1)
    L = w0.size
    t = np.arange(int(20 * fs)) / fs

    def poly5(t0, a, b):
        s = np.clip((t - t0) / 5.0, 0, 1)
        return a + (b - a) * (10 * s**3 - 15 * s**4 + 6 * s**5), (b - a) * 30 * s**2 * (1 - s) ** 2 / 5.0

    (q1, dq1), (q2, dq2) = poly5(5.0, 1.0, 5.0), poly5(12.5, 0.0, -4.0)
    qd, dqd = q1 + q2, dq1 + dq2
    rig = ValveTwin(config_from_dict({"rig": {"kind": "valve"}}))
    q_hist = np.tile(rig.reset(gamma.size, np.arange(gamma.size), fs)[:, 0], (L + 1, 1))
    i_hist = np.zeros((L + 1, gamma.size))
    out = np.zeros((t.size, gamma.size))
    for k in range(t.size):
        f_hat = w1 @ q_hist[1:] - gamma * (w0 @ i_hist[1:])
        e_hat = w0 @ q_hist[:L] - qd[k]
        i = np.clip((dqd[k] - k_p * e_hat - f_hat) / gamma, 0.0, 1.01)
        i_hist[1:] = i_hist[:-1]  # shifted in place: np.roll's values without a new array each tick
        i_hist[0] = i
        q_hist[1:] = q_hist[:-1]
        q_hist[0] = out[k] = rig.step(i[:, None])[:, 0]
    return out - qd[:, None]


@pytest.mark.slow
def test_paper1_campaign_is_feasible_and_gains_matter():
    """Paper 1 Sec. 5.1-5.3: 1 → 5 → 1 l/min; γ = 0.4 m³/(A s²), k_p = 30 1/s tracks (Fig. 9);
    k_p far above oscillates (above the stability region, Fig. 5); k_p far below gives no flow."""
    gamma = np.full(3, 0.4 * 60_000)
    e = _mfc_valve(gamma, np.array([30.0, 300.0, 1.0]))
    rms = np.sqrt(np.mean(e[int(4 * 4000) :] ** 2, axis=0))
    assert rms[0] < 0.4
    assert rms[1] > 3.0
    assert rms[2] > 1.0


# -- shared numerics -------------------------------------------------------------------------------
def test_expm_agrees_with_scipy_on_the_motors_sub_steps_and_on_random_matrices():
    """The twins' own matrix exponential (no scipy import in a campaign worker) against scipy.linalg.expm:
    the motor's augmented sub-step matrix at every rate the shipped campaigns use, with and without
    the electrical lag, and random 5 × 5 batches up to ‖M‖₁ ≈ 15 (3 squarings and more)."""
    from scipy.linalg import expm as scipy_expm

    from labrunner.rigs.sim._integrate import expm, substeps

    a, b = 40.8, 121.3
    for tau in (5e-4, 1e-4):
        for fs in (20.0, 200.0, 1000.0, 4000.0):
            h = 1.0 / (fs * substeps(fs, 1.25e-3))
            M = np.zeros((5, 5))
            M[0, 1], M[1, 1], M[1, 2], M[1, 4], M[2, 2], M[2, 3] = 1.0, -a, b, -b, -1.0 / tau, 1.0 / tau
            np.testing.assert_allclose(expm(M * h), scipy_expm(M * h), rtol=0, atol=4e-15)
    rng = np.random.default_rng(3)
    for scale in (1e-3, 0.1, 0.5, 1.0, 3.0):
        M = rng.normal(size=(64, 5, 5)) * scale
        want = scipy_expm(M)
        err = np.abs(expm(M) - want).max(axis=(1, 2)) / np.abs(want).max(axis=(1, 2))
        assert err.max() < 1e-12, (scale, err.max())
    assert np.array_equal(expm(np.zeros((2, 3, 3))), np.broadcast_to(np.eye(3), (2, 3, 3)))


def test_zoh_discretise_matches_closed_form_and_delay_line_per_run():
    from labrunner.rigs.sim._integrate import DelayLine, zoh_discretise

    a, h = np.array([2.0, 5.0]), 0.1
    Phi, Gam = zoh_discretise(-a[:, None, None] * np.ones((2, 1, 1)), np.ones((2, 1, 1)), h)
    np.testing.assert_allclose(Phi[:, 0, 0], np.exp(-a * h), rtol=1e-14)
    np.testing.assert_allclose(Gam[:, 0, 0], (1 - np.exp(-a * h)) / a, rtol=1e-13)
    line = DelayLine(np.array([0, 3]), fill=-1.0)
    out = np.array([line.push(np.array([k, k], dtype=float)) for k in range(6)])
    np.testing.assert_array_equal(out[:, 0], np.arange(6))
    np.testing.assert_array_equal(out[:, 1], [-1, -1, -1, 0, 1, 2])
