"""Safety monitors (thesis Sec. 3.3): the |du/dt| routine with its own algebraic differentiator,
bounds, non-finite values and the run-time limit, each verdict with monitor, time, value, threshold."""

import numpy as np
import pytest

from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigInfo, Signal
from labrunner.rigs.registry import load_rig
from labrunner.safety import SafetyConfig, SafetyMonitor

FS = 200.0
INFO = RigInfo(
    name="test-motor",
    kind="dcmotor",
    inputs=(Signal("u", "V", -12.0, 12.0),),
    outputs=(Signal("theta", "rad", resolution=2 * np.pi / 2048),),
    fs_range=(10.0, 10_000.0),
    fs_default=FS,
    safe_input=(0.0,),
)


def monitor(*sections, batch=1):
    configs = [SafetyConfig.from_sections(INFO, *sections)] * batch
    m = SafetyMonitor(configs, INFO, FS)
    m.reset(np.zeros((batch, 1)))
    return m


def feed(m, u_of_k, y_of_k=lambda k: 0.0, ticks=400, batch=1):
    """Run ``ticks`` checks; return the first tick at which each run tripped (-1: never)."""
    active = np.ones(batch, dtype=bool)
    first = np.full(batch, -1)
    for k in range(ticks):
        u = np.broadcast_to(np.asarray(u_of_k(k), float), (batch,)).reshape(batch, 1)
        y = np.broadcast_to(np.asarray(y_of_k(k), float), (batch,)).reshape(batch, 1)
        tripped = m.check(k, u, y, active)
        first[tripped] = k
        active &= ~tripped
    return first


@pytest.mark.parametrize("slope, trips", [(100.0, False), (119.0, False), (121.0, True), (400.0, True)])
def test_rate_routine_trips_at_120_volts_per_second(slope, trips):
    """A ramp u = slope·t: the N = 0, α = β = 6 estimator is exact for it, so the routine trips
    exactly when |slope| ≥ 120 V/s, once its window (n_s = 9) is full of the ramp."""
    m = monitor({"max_du_dt": 120.0})
    start = 50
    first = feed(m, lambda k: slope * max(k - start, 0) / FS)
    assert (first[0] >= 0) == trips
    if trips:
        v = m.verdicts[0]
        assert v.monitor == "du_dt" and v.threshold == 120.0
        assert 120.0 <= v.value <= slope * (1 + 1e-9)  # the first estimate over the limit, on the window's rising edge
        assert start < first[0] <= start + 10  # within the estimator's window of the ramp's start
    else:
        assert m.verdicts[0] is None


def test_rate_estimate_of_a_steady_ramp_is_exact():
    m = monitor({"max_du_dt": 1000.0})
    slope = 300.0
    feed(m, lambda k: slope * k / FS, ticks=100)
    rate = np.abs(m._rate.step(np.array([slope * 100 / FS])))
    assert rate[0] == pytest.approx(slope, rel=1e-9)


def test_rate_estimator_window_is_the_thesis_nine_samples_at_200_hz():
    """Thesis Sec. 3.3: N = 0, α = β = 6, ω_c = 200 rad/s at f_s = 200 Hz is a window of n_s = 9
    samples: an impulse in u shows in the rate estimate over exactly nine ticks (the centre tap of
    the antisymmetric α = β kernel is zero)."""
    m = monitor({"max_du_dt": 1e9})
    response = [m._rate.step(np.array([1.0 if k == 3 else 0.0]))[0] for k in range(20)]
    nonzero = [k for k, r in enumerate(response) if r != 0.0]
    assert nonzero[0] == 3 and nonzero[-1] == 3 + 9 - 1 and len(nonzero) >= 8


def test_bounds_nan_and_run_time_verdicts():
    m = monitor(
        {"output_bounds": {"theta": [-1.0, 2.0]}, "input_bounds": {"u": [-5.0, 5.0]}, "max_duration": 1.0}, batch=4
    )
    u = lambda k: np.array([0.0, 6.0 if k >= 10 else 0.0, np.nan if k >= 20 else 0.0, 0.0])  # noqa: E731
    y = lambda k: np.array([0.01 * k, 0.0, 0.0, -2.0 if k >= 30 else 0.0])  # noqa: E731
    first = feed(m, u, y, ticks=400, batch=4)
    # run 0 passes 2.0 rad at k = 201; but the run-time limit of 1 s (k = 200) comes first
    assert list(first) == [200, 10, 20, 30]
    assert (m.verdicts[0].monitor, m.verdicts[0].time, m.verdicts[0].threshold) == ("run_time", 1.0, 1.0)
    assert (m.verdicts[1].monitor, m.verdicts[1].value, m.verdicts[1].threshold) == ("input_high", 6.0, 5.0)
    assert m.verdicts[2].monitor == "non_finite_input" and np.isnan(m.verdicts[2].value)
    assert (m.verdicts[3].monitor, m.verdicts[3].value, m.verdicts[3].threshold) == ("output_low", -2.0, -1.0)
    assert m.verdicts[3].time == pytest.approx(30 / FS)


def test_a_tripped_run_is_reported_once():
    m = monitor({"input_bounds": {"u": [-1.0, 1.0]}}, batch=2)
    active = np.ones(2, dtype=bool)
    hits = [m.check(k, np.array([[2.0], [0.0]]), np.zeros((2, 1)), active).copy() for k in range(3)]
    assert hits[0].tolist() == [True, False]
    active[0] = False
    assert not m.check(3, np.array([[2.0], [0.0]]), np.zeros((2, 1)), active).any()


def reference_verdicts(configs, u, y):
    """Every monitor of every run at every tick, by plain loops: (tick, monitor, value, threshold) of the first trip."""
    from labrunner.differentiators import design

    out = []
    for i, c in enumerate(configs):
        rate = np.full(len(u), np.nan)
        if c.max_du_dt is not None:
            w = design(alpha=c.du_dt_alpha, beta=c.du_dt_beta, omega_c=c.du_dt_omega_c, fs=FS).weights(1)
            x = np.nan_to_num(u[:, i], nan=0.0, posinf=0.0, neginf=0.0)
            past = np.concatenate([np.zeros(w.size - 1), x])  # reset from u0 = 0
            rate = np.abs([np.dot(w, past[k : k + w.size][::-1]) for k in range(len(u))])
        lo_y, hi_y = c.output_bounds.get("theta", (-np.inf, np.inf))
        lo_u, hi_u = c.input_bounds.get("u", (-np.inf, np.inf))
        first = None
        for k in range(len(u)):
            t = k / FS
            for monitor, hit, value, threshold in [
                ("non_finite_input", not np.isfinite(u[k, i]), u[k, i], 0.0),
                ("non_finite_output", not np.isfinite(y[k, i]), y[k, i], 0.0),
                ("output_low", y[k, i] < lo_y, y[k, i], lo_y),
                ("output_high", y[k, i] > hi_y, y[k, i], hi_y),
                ("input_low", u[k, i] < lo_u, u[k, i], lo_u),
                ("input_high", u[k, i] > hi_u, u[k, i], hi_u),
                ("du_dt", c.max_du_dt is not None and rate[k] >= c.max_du_dt, rate[k], c.max_du_dt),
                ("run_time", c.max_duration is not None and t >= c.max_duration, t, c.max_duration),
            ]:
                if hit:
                    first = (k, monitor, value, threshold)
                    break
            if first:
                break
        out.append(first)
    return out


def test_every_tick_screen_misses_no_trip():
    """Random batches with spikes, NaN, inf, bound crossings, fast ramps and run-time limits per run:
    the monitor (a cheap screen per tick, full checks only on flagged ticks) trips each run at
    the tick, with the monitor, value and threshold, that checking everything every tick gives."""
    rng = np.random.default_rng(7)
    B, K = 24, 300
    sections = [
        {
            "max_du_dt": float(rng.choice([None, 60.0, 120.0, 500.0]) or 0) or None,
            "max_duration": float(rng.choice([0.7, 9.0, 9.0])),
            "input_bounds": {"u": [-float(rng.uniform(3, 9)), float(rng.uniform(3, 9))]},
            "output_bounds": {"theta": [-2.0, float(rng.uniform(1, 3))]},
        }
        for _ in range(B)
    ]
    for sec in sections[::5]:
        del sec["input_bounds"], sec["output_bounds"]  # some runs without bounds: only the non-finite checks
    for sec in sections[-3:]:  # quiet runs that never trip
        sec.update(max_du_dt=500.0, max_duration=9.0)
    configs = [SafetyConfig.from_sections(INFO, {k: v for k, v in sec.items() if v is not None}) for sec in sections]
    u = rng.normal(size=(K, B)) * 0.5 + np.linspace(0, 1, B) * np.linspace(0, 8, K)[:, None]
    y = np.cumsum(rng.normal(size=(K, B)) * 0.03, axis=0)
    u[:, -3:] = rng.normal(size=(K, 3)) * 0.1
    for i in range(B - 3):
        k = int(rng.integers(20, 120))
        kind = i % 6
        if kind == 0:
            u[k, i] = np.nan
        elif kind == 1:
            y[k, i] = -np.inf
        elif kind == 2:
            u[k:, i] += 0.02 * np.arange(K - k) * FS / 100  # a ramp of 40 V/s per 0.01 s step
        elif kind == 3:
            y[k, i] = 50.0
        elif kind == 4:
            y[k, i] = -2.5
    expected = reference_verdicts(configs, u, y)
    m = SafetyMonitor(configs, INFO, FS)
    m.reset(np.zeros((B, 1)))
    active = np.ones(B, dtype=bool)
    first = [None] * B
    for k in range(K):
        tripped = m.check(k, u[k][:, None], y[k][:, None], active)
        for i in np.flatnonzero(tripped):
            first[i] = k
        active &= ~tripped
    assert sum(e is not None for e in expected) > B // 2 and any(e is None for e in expected)  # the data exercise both
    for i, e in enumerate(expected):
        if e is None:
            assert first[i] is None and m.verdicts[i] is None
            continue
        v = m.verdicts[i]
        assert (first[i], v.monitor) == e[:2], i
        assert v.time == e[0] / FS and v.threshold == e[3]
        assert v.value == pytest.approx(e[2], rel=1e-12, nan_ok=True)


def test_campaign_section_overrides_the_rig_file():
    config = SafetyConfig.from_sections(
        INFO, {"max_du_dt": 120.0, "input_bounds": {"u": [-12, 12]}}, {"max_du_dt": 60.0}
    )
    assert config.max_du_dt == 60.0 and config.input_bounds == {"u": (-12.0, 12.0)}


@pytest.mark.parametrize(
    "section, field",
    [
        ({"max_du_dt": -1.0}, "safety.max_du_dt"),
        ({"max_du_dt": float("nan")}, "safety.max_du_dt"),
        ({"speed": 1.0}, "safety.speed"),
        ({"output_bounds": {"omega": [0, 1]}}, "safety.output_bounds.omega"),
        ({"output_bounds": {"theta": [1, 0]}}, "safety.output_bounds.theta"),
        ({"input_bounds": {"u": [1]}}, "safety.input_bounds.u"),
        ({"du_dt_alpha": 0.0}, "safety.du_dt_alpha"),
        ({"motion_output": "q"}, "safety.motion_output"),
    ],
)
def test_bad_sections_name_the_key(section, field):
    with pytest.raises(InvalidParameter) as err:
        SafetyConfig.from_sections(INFO, section)
    assert err.value.field == field


def test_plate_air_gaps_are_bounded_at_the_magnets_not_at_the_sensors():
    """Paper 2 Sec. 4 limits the magnets' air gaps to 0.8–5.5 mm. Tilted about y, the plate's
    magnets (l_fx = 0.1825 m out) come closer than its sensors (l_dx = 0.135 m): at 0.70 mm gaps
    the sensors still read 0.91 mm, and the rig file's bounds trip on h1, valued as the twin's
    own magnet gap (its rigid pose, not eq. (4))."""
    plate = load_rig("plate-sim")
    twin = load_rig({"rig": {"kind": "plate"}, "noise": {"sensor_std": 0.0, "current_std": 0.0}})
    twin.reset(1, [0], 32_000.0)
    x = np.array([[1.5e-3, 0.0, 4.4e-3, 0.0]])  # (z, φ_x, φ_y, mode)
    twin.set_state(x, np.zeros((1, 4)))
    gaps, y = twin.magnet_gaps(), twin._sensors(np.zeros((1, 4)))
    assert gaps[0, 0] < 0.8e-3 and (y > 0.8e-3).all()
    configs = [SafetyConfig.from_sections(plate.info, plate.config.safety)]
    m = SafetyMonitor(configs, plate.info, 32_000.0)
    m.reset(np.zeros((1, 4)))
    tripped = m.check(10, np.full((1, 4), 2.0), y, np.ones(1, dtype=bool))
    v = m.verdicts[0]
    assert tripped[0] and (v.monitor, v.threshold) == ("output_low:h1", 0.8e-3)
    assert v.value == pytest.approx(gaps[0, 0], rel=1e-12)
    x[0, 2] = 2e-3  # a milder tilt: every gap inside the bounds, nothing trips
    twin.set_state(x)
    assert not m.check(11, np.full((1, 4), 2.0), twin._sensors(np.zeros((1, 4))), np.ones(1, dtype=bool)).any()


def test_output_bounds_may_name_the_rigs_derived_signals_only():
    plate = load_rig("plate-sim")
    assert SafetyConfig.from_sections(plate.info, {"output_bounds": {"h3": [1e-3, 5e-3]}}).output_bounds == {
        "h3": (1e-3, 5e-3)
    }
    with pytest.raises(
        InvalidParameter, match=r"safety\.output_bounds\.h5: unknown signal; rig 'plate-sim' has .*'h4'"
    ):
        SafetyConfig.from_sections(plate.info, {"output_bounds": {"h5": [1e-3, 5e-3]}})
    with pytest.raises(InvalidParameter, match=r"safety\.motion_output"):  # motion is measured, not derived
        SafetyConfig.from_sections(plate.info, {"motion_output": "h1"})
