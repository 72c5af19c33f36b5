"""Plate twin (labrunner.rigs.sim.plate) against analytic behaviour of paper 2's plate model."""

import itertools

import numpy as np
import pytest

from labrunner.errors import InvalidParameter
from labrunner.plate_geometry import PlateGeometry, magnet_force
from labrunner.rigs.registry import load_rig
from labrunner.rigs.sim.plate import PlateTwin

FS = 32_000.0
QUIET = {"sensor_std": 0.0, "current_std": 0.0}


def twin(parameters=None, noise=None):
    return load_rig(
        {"rig": {"kind": "plate"}, "parameters": parameters or {}, "noise": QUIET if noise is None else noise}
    )


def run(rig, currents, seconds, batch=1, seeds=None, overrides=None):
    y = rig.reset(batch, np.arange(batch) if seeds is None else seeds, FS, overrides)
    ys = [y]
    for _ in range(int(seconds * FS)):
        ys.append(rig.step(np.broadcast_to(currents, (batch, 4))))
    return np.array(ys)


def lift_current(gap=5.5e-3):
    """Current per magnet whose four forces carry the plate's weight at ``gap`` (eq. (2), d = 250 h)."""
    g = PlateGeometry()
    return 250 * gap * np.sqrt(g.m * g.g / 4)


def test_registry_info():
    rig = twin()
    assert isinstance(rig, PlateTwin)
    assert [s.name for s in rig.info.inputs] == ["i1", "i2", "i3", "i4"]
    assert [s.name for s in rig.info.outputs] == ["y1", "y2", "y3", "y4"]
    assert rig.info.fs_default == 32_000.0 and rig.info.input_hi.tolist() == [8.0] * 4
    assert rig.info.constants["m"] == 4.69 and rig.info.constants["lambda_inv_sqrt"] == 250.0


def test_no_current_rests_on_the_screws():
    ys = run(twin(), 0.0, 0.2)
    np.testing.assert_allclose(ys[:, 0], 5.5e-3, atol=5e-6)  # at rest, the plate's sag of a few µm aside
    assert np.ptp(ys[:, 0, :]) < 1e-6


def test_sensor_noise_is_white_with_the_rig_files_std():
    """The [noise] sensor_std (0.5 µm in rigs/plate-sim.toml) is added to each sensor, uncorrelated."""
    std = load_rig("plate-sim").config.noise["sensor_std"]
    noisy = run(twin(noise={"sensor_std": std, "current_std": 0.0}), 0.0, 0.05)
    clean = run(twin(), 0.0, 0.05)
    n = (noisy - clean).reshape(-1, 4)
    assert np.std(n) == pytest.approx(std, rel=0.05)
    assert np.abs(np.corrcoef(n.T) - np.eye(4)).max() < 0.1  # 4 standard errors at 1600 samples
    assert abs(np.corrcoef(n[1:, 0], n[:-1, 0])[0, 1]) < 0.1  # white in time


def test_open_loop_unstable_between_stick_and_snap():
    """2 % below the lift-off current the plate stays on the screws; 2 % above it snaps to the top stop:
    no stable equilibrium in between (the magnet force grows as the gap shrinks)."""
    i0 = lift_current()
    below = run(twin(), 0.98 * i0, 0.3)
    assert np.all(below[-1] > 5.49e-3)
    above = run(twin(), 1.02 * i0, 0.3)
    assert np.all(above[-1] < 0.8e-3)  # beyond the 0.8 mm safety limit, at the upper stop
    assert np.all(above[-1] > 0.3e-3)  # ... but the stop holds it off the yokes
    big = run(twin(), 8.0, 0.1)
    assert np.all(big[-1] < 0.8e-3)


def test_initial_acceleration_after_lift_off():
    """With 1.5× the lift-off force the centre rises with |z̈| ≈ 0.5 g at first (rigid body, eq. (1))."""
    rig = twin({"mode_mass": 100.0})
    ys = run(rig, np.sqrt(1.5) * lift_current(), 0.004)
    rise = ys[0, :3].mean() - ys[-1, :3].mean()
    t = 0.004
    assert rise == pytest.approx(0.5 * 0.5 * 9.81 * t**2, rel=0.1)


def test_forces_follow_eq2():
    rig = twin()
    rig.reset(1, [0], FS)
    gaps = np.array([[2e-3, 3e-3, 4e-3, 5e-3]])
    np.testing.assert_allclose(rig.magnet_forces(np.full((1, 4), 4.0), gaps), magnet_force(2.0, gaps), rtol=1e-12)


def test_batch_equals_single_runs_and_seeds_reproduce():
    rig = twin(noise={})
    i = np.array([3.0, 3.5, 4.0, 4.5])
    batch = run(rig, i, 0.02, batch=3, seeds=[5, 6, 7])
    for b, seed in enumerate([5, 6, 7]):
        single = run(rig, i, 0.02, batch=1, seeds=[seed])
        np.testing.assert_allclose(batch[:, b], single[:, 0], rtol=0, atol=1e-15)
    assert not np.allclose(batch[:, 0], batch[:, 1])  # different seeds, different noise


def test_per_run_overrides():
    """A 10 % lighter plate lifts off at a current that leaves the nominal one on the screws."""
    i = 0.97 * lift_current()
    ys = run(twin(), i, 0.3, batch=2, overrides={"m": np.array([4.69, 0.9 * 4.69])})
    assert ys[-1, 0, 0] > 5.49e-3 and ys[-1, 1, 0] < 0.8e-3


def test_substeps_converge():
    """In flight, one sub-step per sample (the default at 32 kHz) agrees with 32 to within 0.01 % of the motion."""

    def flight(max_substep):
        rig = twin({"max_substep": max_substep})
        rig.reset(1, [0], FS)
        rig.set_state([[4e-3, 1e-3, -1e-3, 0.0]])  # tilted, in mid air, at rest
        i = np.array([[1.03, 1.0, 0.98, 1.0]]) * lift_current(4e-3)
        return np.array([rig.step(i) for _ in range(int(0.015 * FS))])

    coarse, fine = flight(32e-6), flight(1e-6)
    assert np.ptp(fine) > 5e-4  # it moved by more than half a millimetre
    assert np.abs(coarse - fine).max() < 1e-4 * np.ptp(fine)


def step_matrix(K, C, h):
    """(8, 8) map (x, v) → (x⁺, v⁺) of one drift-kick-drift step of ẍ = −K x − C v (C on the step's first v)."""
    eye, zero = np.eye(4), np.zeros((4, 4))
    x_half = np.hstack([eye, 0.5 * h * eye])
    v1 = np.hstack([zero, eye]) + h * (-K @ x_half - C @ np.hstack([zero, eye]))
    return np.vstack([x_half + 0.5 * h * v1, v1])


def linearised_on_the_stops(rig):
    """K, C of the plate resting with all four corners on the screws (no current): ẍ = −K δx − C v."""
    G, inv_m = rig._G, np.diag(rig._inv_mass[0])
    K = inv_m @ (rig._k_c[0, 0] * G @ G.T) + np.diag(rig._stiff[0])
    C = inv_m @ (rig._c_c[0, 0] * G @ G.T) + np.diag(rig._damp[0])
    return K, C


def test_twin_steps_by_the_analysed_scheme():
    """On the screws without current the twin is linear about its rest: one sample is step_matrix exactly."""
    rig = twin()
    rig.reset(1, [0], FS)
    rest = rig.x.copy()
    dx, dv = np.array([[2e-6, 1e-5, -1e-5, 1e-6]]), np.array([[1e-4, -2e-3, 1e-3, 5e-4]])
    rig.set_state(rest + dx, dv)
    rig.step(np.zeros((1, 4)))
    K, C = linearised_on_the_stops(rig)
    expected = step_matrix(K, C, 1.0 / (FS * rig.substeps)) @ np.concatenate([dx[0], dv[0]])
    assert np.allclose(np.concatenate([rig.x[0] - rest[0], rig.v[0]]), expected, rtol=1e-7, atol=1e-13)


def test_integration_stable_for_every_allowed_parameter():
    """Spectral radius of one integration step with all four stops engaged ≤ 1 at the parameter extremes."""
    worst = 0.0
    for m, J, mm, w, z, cw in itertools.product([0.5, 50], [1e-3, 5], [0.05, 100], [100, 5000], [0, 1], [1e3, 2e4]):
        rig = twin(
            {"m": m, "J_x": J, "J_y": J, "mode_mass": mm, "mode_omega": w, "contact_zeta": z, "contact_omega": cw}
        )
        rig.reset(1, [0], FS)
        step = step_matrix(*linearised_on_the_stops(rig), 1.0 / (FS * rig.substeps))
        worst = max(worst, np.abs(np.linalg.eigvals(step)).max())
    assert worst <= 1.0 + 1e-9


def test_faults_from_the_base_class():
    rig = load_rig(
        {"rig": {"kind": "plate"}, "noise": QUIET, "faults": {"t_start": 0.0, "sensor_step": [2e-4, 0, 0, 0]}}
    )
    y0 = rig.reset(1, [0], FS)
    assert y0[0, 0] - y0[0, 1] == pytest.approx(2e-4, abs=1e-6)


@pytest.mark.parametrize(
    "section, key, value, match",
    [
        ("parameters", "m", -1.0, "parameters.m"),
        ("parameters", "top_gap", 9e-4, None),
        ("parameters", "screw_gap", 8e-4, "screw_gap"),
        ("parameters", "wobble", 1.0, "parameters.wobble"),
        ("noise", "sensor_std", -1e-6, "noise.sensor_std"),
    ],
)
def test_rig_file_validation(section, key, value, match):
    if match is None:
        twin({key: value})  # a valid value passes
        return
    with pytest.raises(InvalidParameter, match=match):
        load_rig({"rig": {"kind": "plate"}, section: {key: value}})


def test_override_validation():
    rig = twin()
    with pytest.raises(InvalidParameter, match="overrides.l_dx"):
        rig.reset(1, [0], FS, {"l_dx": np.array([0.1])})
    with pytest.raises(InvalidParameter, match="overrides.m"):
        rig.reset(1, [0], FS, {"m": np.array([-3.0])})
