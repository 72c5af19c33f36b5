"""The run engine on the simulated DC motor: thesis-like closed loops (Sec. 3.5.1), the safety
routine's abort, no-motion runs, lockstep batches equal single runs, failures leave the rig safe."""

from pathlib import Path

import numpy as np
import pytest

from labrunner import engine, stability
from labrunner.campaign import spec
from labrunner.errors import InvalidParameter
from labrunner.rigs import registry

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = spec.load(ROOT / "campaigns" / "quickstart.toml", root=ROOT)  # γ = b, k_p = 50, α = β = 9, ω_c = 200, 200 Hz
A, B, DELAY = 39.44, 108.55, 0.035  # rigs/dcmotor-sim.toml; δ_t of the thesis's differentiator


def point(**gains):
    return CAMPAIGN.resolve({f"controller.{k}": v for k, v in gains.items()})


def run(points, seeds=None, rig="dcmotor-sim", **kw):
    with registry.load_rig(rig, search=[ROOT / "rigs"]) as r:
        return engine.run_batch(
            points,
            r,
            fs=CAMPAIGN.fs,
            duration=CAMPAIGN.duration,
            seeds=seeds or list(range(len(points))),
            rig_safety=CAMPAIGN.rig_safety,
            **kw,
        )


@pytest.fixture(scope="module")
def thesis_points():
    """Nominal tuning, far above bound (2.46), and a tiny input (huge γ, small k_p)."""
    hi = stability.bounds("mfc1-motor", gamma=B, delay=DELAY, a=A, b=B)["k_p"][1]
    points = [point(gamma=B, k_p=50.0), point(gamma=B, k_p=5 * hi), point(gamma=1e4, k_p=0.1)]
    return points, run(points)


def test_nominal_mfc_tracks_the_poly5_reference(thesis_points):
    result = thesis_points[1][0]
    assert result.outcome.status == "completed"
    assert result.n_samples == int(CAMPAIGN.duration * CAMPAIGN.fs)
    e = result.signals["e_omega"]
    assert result.metrics["rms_error"] == pytest.approx(np.sqrt(np.mean(e**2)))
    assert result.metrics["rms_error"] < 1.0  # rad/s, against a 20 rad/s level
    assert np.max(np.abs(e[-100:])) < 0.5  # friction compensated once the reference is back at 0
    u = result.signals["u"]
    assert result.metrics["input_energy"] == pytest.approx(np.sum(u**2))
    np.testing.assert_allclose(result.signals["omega"] - result.signals["ref_omega"], e)


def test_far_above_bound_246_is_aborted_by_the_rate_routine(thesis_points):
    result = thesis_points[1][1]
    out = result.outcome
    assert out.status == "aborted" and out.monitor == "du_dt"
    assert out.value >= out.threshold == 120.0
    abort = round(out.time * CAMPAIGN.fs)
    assert result.n_samples == abort + 1  # signals end at the abort sample
    theta = result.signals["theta"]
    moved = int(np.flatnonzero(theta != theta[0])[0])  # static friction holds the load until u breaks it away
    # the routine stops the diverging loop within a few samples of its start: 9 here, about one
    # window (n_s = 9) of its rate estimator
    assert 0 < abort - moved <= 12


def test_tiny_input_is_no_motion(thesis_points):
    result = thesis_points[1][2]
    assert result.outcome.status == "no-motion"
    theta = result.signals["theta"]
    assert np.max(np.abs(theta - theta[0])) <= 2 * np.pi / 2048  # never beyond one encoder count


def test_batch_equals_single_runs(thesis_points):
    points, batch = thesis_points
    for i, p in enumerate(points):
        (single,) = run([p], seeds=[i])
        assert single.outcome.status == batch[i].outcome.status and single.outcome.time == batch[i].outcome.time
        if batch[i].outcome.value is not None:  # the rate estimate sums its taps in another order per batch size
            assert single.outcome.value == pytest.approx(batch[i].outcome.value, rel=1e-12)
        assert single.signals.keys() == batch[i].signals.keys()
        for name, trace in single.signals.items():
            np.testing.assert_allclose(trace, batch[i].signals[name], rtol=0, atol=1e-12, err_msg=name)


def test_runs_with_their_own_safety_and_reference_sections_keep_them_in_a_batch():
    """Points share validated safety limits and trajectories only where their sections are equal:
    a run with its own rate limit or levels gets them, the others the campaign's (as single runs)."""
    own_limit, own_levels = point(gamma=B, k_p=20.0), point(gamma=B, k_p=20.0)
    own_limit["safety"] = {"max_du_dt": 5.0}
    own_levels["reference"] = dict(own_levels["reference"], levels=[0.0, 5.0, 0.0])
    points = [point(gamma=B, k_p=20.0), own_limit, own_levels, point(gamma=B, k_p=20.0)]
    batch = run(points, seeds=[0] * 4)
    assert batch[1].outcome.status == "aborted" and batch[1].outcome.threshold == 5.0
    assert batch[0].outcome.status == batch[3].outcome.status == "completed"
    assert np.max(batch[2].signals["ref_omega"]) == pytest.approx(5.0) and np.max(
        batch[0].signals["ref_omega"]
    ) == pytest.approx(20.0)
    for p, result in zip(points, batch):
        (single,) = run([p], seeds=[0])
        assert (single.outcome.status, single.outcome.time, single.outcome.threshold) == (
            result.outcome.status,
            result.outcome.time,
            result.outcome.threshold,
        )
        for name, trace in single.signals.items():
            np.testing.assert_array_equal(trace, result.signals[name], err_msg=name)


def test_channels_have_log_roles_and_si_units(thesis_points):
    ch = thesis_points[1][0].channels
    assert ch["outputs"] == ["theta"] and ch["controlled"] == ["omega"] and ch["inputs"] == ["u"]
    assert ch["references"] == ["ref_omega"] and ch["errors"] == ["e_omega"]
    assert {"f_hat_omega", "e_hat_omega"} <= set(ch["estimates"])
    assert ch["units"]["theta"] == "rad" and ch["units"]["omega"] == "rad/s" and ch["units"]["u"] == "V"
    assert ch["units"]["e_omega"] == ch["units"]["ref_omega"] == "rad/s"
    # first-order model Ω̇ = f + γu: f̂ is an angular acceleration, ê an angular velocity
    assert ch["units"]["f_hat_omega"] == "rad/s²" and ch["units"]["e_hat_omega"] == "rad/s"


@pytest.mark.parametrize(
    ("unit", "n", "expected"),
    [
        ("rad", 2, "rad/s²"),
        ("rad/s", 1, "rad/s²"),
        ("m/s²", 1, "m/s³"),
        ("m", 0, "m"),
        ("l/min", 1, "l/min/s"),
        ("", 2, ""),
    ],
)
def test_per_second_is_the_unit_of_a_time_derivative(unit, n, expected):
    assert engine.per_second(unit, n) == expected


def test_plate_estimates_carry_second_order_units():
    campaign = spec.load(ROOT / "campaigns" / "plate-alpha-omegac.toml", root=ROOT)
    points, _ = spec.plan(campaign)
    p = campaign.resolve(points[0].parameters)
    with registry.load_rig(campaign.rig_ref, search=campaign.rig_search) as r:
        (result,) = engine.run_batch([p], r, fs=campaign.fs, duration=0.01, seeds=[0], rig_safety=campaign.rig_safety)
    units = result.channels["units"]
    assert (
        units["y1"] == "m" and units["f_hat_y1"] == "m/s²" and units["de_hat_y1"] == "m/s" and units["e_hat_y1"] == "m"
    )


def test_sink_streams_run_zero_in_blocks(thesis_points):
    blocks = []
    (result,) = run([thesis_points[0][0]], seeds=[0], sink=lambda first, block: blocks.append((first, block)))
    assert [first for first, _ in blocks] == [0]  # 1000 samples: one (final, partial) block
    for name, trace in result.signals.items():
        np.testing.assert_array_equal(np.concatenate([b[name] for _, b in blocks]), trace)


def test_a_crash_mid_run_fails_the_open_runs_and_leaves_the_rig_safe(monkeypatch):
    rig = registry.load_rig("dcmotor-sim", search=[ROOT / "rigs"])
    step, calls, safe = rig._step, [0], []

    def flaky(u):
        calls[0] += 1
        if calls[0] == 100:
            raise RuntimeError("encoder lost")
        return step(u)

    monkeypatch.setattr(rig, "_step", flaky)
    original_safe = rig.safe_state
    monkeypatch.setattr(rig, "safe_state", lambda mask=None: (safe.append(mask), original_safe(mask)))
    results = engine.run_batch(
        [point(gamma=B, k_p=50.0)] * 2,
        rig,
        fs=CAMPAIGN.fs,
        duration=CAMPAIGN.duration,
        seeds=[0, 1],
        rig_safety=CAMPAIGN.rig_safety,
    )
    assert [r.outcome.status for r in results] == ["failed", "failed"]
    assert "RuntimeError: encoder lost" in results[0].outcome.message
    assert results[0].n_samples == 100
    assert np.isfinite(results[0].signals["u"]).all()  # the crash came after tick 99 was logged
    assert safe and safe[-1] is None  # the whole batch sent to its safe state
    np.testing.assert_array_equal(rig.applied_input, 0.0)


def test_bad_configuration_raises_before_the_rig_moves(monkeypatch):
    rig = registry.load_rig("dcmotor-sim", search=[ROOT / "rigs"])
    monkeypatch.setattr(rig, "reset", lambda *a, **k: pytest.fail("the rig was reset"))
    with pytest.raises(InvalidParameter) as err:
        engine.run_batch([point(gamma=-1.0, k_p=50.0)], rig, fs=CAMPAIGN.fs, duration=1.0, seeds=[0])
    assert err.value.field == "controller.gamma"


def test_a_tripped_run_is_safe_in_the_same_tick(thesis_points):
    """The input that trips the routine never reaches the rig: in the tick of the abort the rig
    applies its safe input to that run, while the other runs go on with their own inputs."""
    points = thesis_points[0][:2]  # nominal, and far above bound (2.46)
    rig = registry.load_rig("dcmotor-sim", search=[ROOT / "rigs"])
    step, applied = rig._step, []
    rig._step = lambda u: (applied.append(u.copy()), step(u))[1]
    nominal, aborted = engine.run_batch(
        points, rig, fs=CAMPAIGN.fs, duration=CAMPAIGN.duration, seeds=[0, 1], rig_safety=CAMPAIGN.rig_safety
    )
    applied = np.array(applied)[:, :, 0]
    k = round(aborted.outcome.time * CAMPAIGN.fs)
    assert aborted.outcome.status == "aborted" and aborted.signals["u"][k] != 0.0  # the commanded input
    np.testing.assert_array_equal(applied[:k, 1], aborted.signals["u"][:k])
    np.testing.assert_array_equal(applied[k:, 1], 0.0)  # from the abort tick on: the safe input
    np.testing.assert_array_equal(applied[:, 0], nominal.signals["u"][: len(applied)])
    assert nominal.outcome.status == "completed"


def test_valve_run_whose_flow_never_rises_is_no_motion():
    """Paper 1's valve: with its MFC gains (γ = 0.4 m³/(A s²), k_p = 30 1/s) the flow rises through
    the sensor's range; with a huge γ the current stays far below the main stage's ≈ 50 % threshold,
    the reading never passes the sensor's 1.2 l/min (the rig file's motion_min_level): no-motion."""
    config = registry.load_rig_config("valve-sim", search=[ROOT / "rigs"])

    def point(gamma):
        return {"controller": {"kind": "mfc1", "output": "flow", "gamma": gamma, "k_p": 30.0},
                "differentiator": {"alpha": 2, "beta": 2, "omega_c": 250.0},
                "reference": {"kind": "setpoints", "levels": [1.0, 5.0, 1.0], "transition": 0.3, "hold": 0.3}}  # fmt: skip

    with registry.load_rig(config) as rig:
        tracked, tiny = engine.run_batch(
            [point(0.4), point(1e4)], rig, fs=4000.0, duration=1.5, seeds=[0, 1], rig_safety=config.safety
        )
    assert tracked.outcome.status == "completed" and tracked.signals["q"].max() > 3.0
    assert tiny.outcome.status == "no-motion" and tiny.signals["q"].max() <= 1.2
    assert tiny.signals["i"].max() < 0.5 * 1.01
