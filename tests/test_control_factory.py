"""Factory: registry, per-run arrays, key validation with dotted paths; open-loop and valve
feed-forward baselines (paper 1 eq. (11))."""

import copy

import numpy as np
import pytest

from labrunner.control import factory
from labrunner.control.baselines import KAPPA_PAPER1, LPM
from labrunner.control.trajectories import Setpoints
from labrunner.errors import InvalidParameter
from labrunner.rigs.base import RigInfo, Signal

MOTOR = RigInfo(
    "motor", "dcmotor", (Signal("u", "V", -12.0, 12.0),), (Signal("theta", "rad"),), (1.0, 2000.0), 200.0, (0.0,)
)
VALVE = RigInfo(
    "valve", "valve", (Signal("i", "A", 0.0, 1.01),), (Signal("q", "l/min"),), (1.0, 4000.0), 4000.0, (0.0,)
)
VALVE_DP = RigInfo(
    "valve-dp",
    "valve",
    (Signal("i", "A", 0.0, 1.01),),
    (Signal("q", "l/min"), Signal("dp", "Pa")),
    (1.0, 4000.0),
    4000.0,
    (0.0,),
)

QUICKSTART = {  # the campaign file of issue 6, one resolved point
    "controller": {"kind": "mfc1", "output": "velocity", "gamma": 108.55, "k_p": 50.0},
    "differentiator": {"alpha": 9, "beta": 9, "N": 0, "omega_c": 200.0, "method": "midpoint"},
    "reference": {"kind": "setpoints", "levels": [0.0, 20.0, 0.0], "transition": 1.0, "hold": 1.0},
}
ANGLE = {
    "controller": {"kind": "mfc2", "output": "angle", "gamma": 108.55, "k_p": 100.0, "k_d": 50.0},
    "differentiator": {"alpha": 9, "beta": 9, "omega_c": 200.0, "method": "analytic"},
    "reference": {"kind": "setpoints", "levels": [0.0, 3.14, 0.0], "transition": 0.5, "hold": 0.5},
}


def edit(base, path, value):
    """A copy of ``base`` with the dotted ``path`` set to ``value`` (deleted if value is ...)."""
    p = copy.deepcopy(base)
    section, key = path.split(".")
    if value is ...:
        p[section].pop(key, None)
    else:
        p.setdefault(section, {})[key] = value
    return p


def test_registry_names_every_kind_and_imports_lazily():
    assert factory.REGISTRY["plate-mfc"] == "labrunner.control.plate:build_plate_mfc"
    assert factory.REGISTRY["plate-mbc"] == "labrunner.control.plate_mbc:build_plate_mbc"
    assert {"mfc1", "mfc1-ff", "mfc2", "open-loop", "valve-ffc"} <= set(factory.REGISTRY)
    with pytest.raises(InvalidParameter) as err:
        factory.builder("pid")
    assert err.value.field == "controller.kind"


def test_builds_per_run_arrays_for_the_quickstart_grid():
    gammas, kps = [1.0, 10.0, 108.55, 1e4], [0.1, 1.0, 50.0, 1e3]
    points = [edit(edit(QUICKSTART, "controller.gamma", g), "controller.k_p", k) for g, k in zip(gammas, kps)]
    c, ref = factory.build(points, MOTOR, 200.0)
    assert c.batch == 4 and c.output_names == ("omega",) and c.n_inputs == 1
    np.testing.assert_array_equal(c.gamma[:, 0], gammas)
    np.testing.assert_array_equal(c.k_p[:, 0], kps)
    np.testing.assert_array_equal(c.u_min[:, 0], -12.0)
    assert ref.evaluate(np.array([2.0])).shape == (1, 4, 1, 4) and ref.duration == pytest.approx(5.0)
    c2, _ = factory.build([ANGLE], MOTOR, 200.0)
    assert c2.output_names == ("theta",) and set(c2.estimates) == {"f_hat", "e_hat", "de_hat"}
    factory.validate(QUICKSTART, MOTOR, 200.0)


BAD = [
    (edit(QUICKSTART, "controller.kind", "pid"), "controller.kind"),
    (edit(QUICKSTART, "controller.gain", 1.0), "controller.gain"),
    (edit(QUICKSTART, "controller.gamma", 0.0), "controller.gamma"),
    (edit(QUICKSTART, "controller.gamma", -5.0), "controller.gamma"),
    (edit(QUICKSTART, "controller.gamma", ...), "controller.gamma"),
    (edit(QUICKSTART, "controller.gamma", "big"), "controller.gamma"),
    (edit(QUICKSTART, "controller.k_p", float("nan")), "controller.k_p"),
    (edit(QUICKSTART, "controller.k_p", -1.0), "controller.k_p"),
    (edit(QUICKSTART, "controller.k_p", True), "controller.k_p"),
    (edit(QUICKSTART, "controller.k_d", 1.0), "controller.k_d"),  # first order has no k_d
    (edit(QUICKSTART, "controller.output", "angle"), "controller.output"),  # θ needs a second-order law
    (edit(QUICKSTART, "controller.output", "torque"), "controller.output"),
    (edit(QUICKSTART, "controller.output", "flow"), "controller.output"),  # the motor has no flow output
    (edit(QUICKSTART, "controller.u_max", 24.0), "controller.u_max"),  # beyond the rig's ±12 V
    (edit(edit(QUICKSTART, "controller.u_min", 5.0), "controller.u_max", 5.0), "controller.u_max"),
    (edit(QUICKSTART, "controller.i_min", 0.5), "controller.i_min"),  # a valve option
    (edit(QUICKSTART, "controller.filter", "both"), "controller.filter"),
    (edit(ANGLE, "differentiator.alpha", 1), "differentiator.alpha"),  # n = 2 needs min(α, β) > 1
    (edit(ANGLE, "differentiator.beta", 0.5), "differentiator.beta"),
    (edit(ANGLE, "controller.k_d", ...), "controller.k_d"),
    (edit(QUICKSTART, "differentiator.omega_c", 800.0), "differentiator.omega_c"),  # above Nyquist π·200
    (edit(QUICKSTART, "differentiator.window", 0.1), "differentiator.omega_c"),  # both omega_c and window
    (edit(QUICKSTART, "differentiator.omega_c", ...), "differentiator.omega_c"),
    (edit(QUICKSTART, "differentiator.theta", 0.5), "differentiator.theta"),  # θ only for N > 0
    (edit(QUICKSTART, "differentiator.N", 1.5), "differentiator.N"),
    (edit(QUICKSTART, "differentiator.N", "one"), "differentiator.N"),
    (edit(QUICKSTART, "differentiator.alpha", [9]), "differentiator.alpha"),
    (edit(QUICKSTART, "differentiator.method", "simpson"), "differentiator.method"),
    (edit(QUICKSTART, "differentiator.order", 2), "differentiator.order"),
    (edit(QUICKSTART, "reference.kind", "ramp"), "reference.kind"),
    (edit(QUICKSTART, "reference.levels", ...), "reference.levels"),
    (edit(QUICKSTART, "reference.transition", -1.0), "reference.transition"),
    (edit(QUICKSTART, "reference.hold", [1.0, 2.0]), "reference.hold"),
    (edit(QUICKSTART, "reference.delay", "yes"), "reference.delay"),
    (edit(QUICKSTART, "reference.speed", 1.0), "reference.speed"),
]


@pytest.mark.parametrize("point, field", BAD, ids=[f"{f}-{i}" for i, (_, f) in enumerate(BAD)])
def test_bad_points_name_the_key(point, field):
    with pytest.raises(InvalidParameter) as err:
        factory.validate(point, MOTOR, 200.0)
    assert err.value.field == field
    assert str(err.value).startswith(field + ": ")


def test_batch_level_errors():
    with pytest.raises(InvalidParameter, match="one batch needs one kind"):
        factory.build([QUICKSTART, ANGLE], MOTOR, 200.0)
    with pytest.raises(InvalidParameter) as err:
        factory.build([QUICKSTART], MOTOR, 5000.0)
    assert err.value.field == "campaign.fs"
    with pytest.raises(InvalidParameter) as err:
        factory.build([QUICKSTART, edit(QUICKSTART, "controller.output", ...)], MOTOR, 200.0)
    assert err.value.field == "controller.output"


def test_open_loop_drives_the_input_trajectory_saturated():
    steps = {
        "controller": {"kind": "open-loop"},
        "reference": {"kind": "steps", "levels": [-12.0, -6.0, 6.0, 20.0], "durations": 1.0},
    }
    sine = {
        "controller": {"kind": "open-loop", "u_max": 5.0},
        "reference": {"kind": "sine", "amplitude": 6.0, "frequency": 1.0, "duration": 4.0},
    }
    c, ref = factory.build([steps, sine], MOTOR, 100.0)
    assert c.output_names == ("u_cmd",)
    t = np.arange(400) / 100.0
    R = ref.evaluate(t)
    c.reset(np.zeros((2, 1)))
    u = np.array([c.step(np.zeros((2, 1)), R[k]) for k in range(400)])[:, :, 0]
    np.testing.assert_allclose(u[:, 0], np.clip(R[:, 0, 0, 0], -12, 12))
    np.testing.assert_allclose(u[:, 1], np.clip(6 * np.sin(2 * np.pi * t), -12, 5.0))
    assert u[:, 0].max() == 12.0
    with pytest.raises(InvalidParameter) as err:
        factory.build([{**steps, "differentiator": {"alpha": 1}}], MOTOR, 100.0)
    assert err.value.field == "differentiator"


def test_valve_feed_forward_paper1_eq11():
    """i = κ q_d/√Δp + i_0 with κ = 6.596·10⁵, i_0 = 0.53 A (paper 1 Sec. 5.3), Δp = 5 bar."""
    p = {
        "controller": {"kind": "valve-ffc", "dp": 5e5},
        "reference": {"kind": "setpoints", "levels": [1.0, 5.0, 1.0], "transition": 5.0, "hold": 5.0},
    }
    c, ref = factory.build([p], VALVE, 4000.0)
    c.reset(np.zeros((1, 1)))
    for t, q_d in ((0.0, 1.0), (10.0, 5.0)):
        u = c.step(np.array([[0.7]]), ref.evaluate([t])[0])
        assert u[0, 0] == pytest.approx(KAPPA_PAPER1 * q_d * LPM / np.sqrt(5e5) + 0.53, rel=1e-12)
        assert c.controlled[0, 0] == 0.7
    assert 0.55 < u[0, 0] < 1.01  # a few tenths of an ampere above i_0, within i_max
    measured = {"controller": {"kind": "valve-ffc", "kappa": 1e5, "i_0": 0.4}, "reference": p["reference"]}
    c2, ref2 = factory.build([measured], VALVE_DP, 4000.0)
    c2.reset(np.array([[0.0, 4e5]]))
    u2 = c2.step(np.array([[3.0, 4e5]]), ref2.evaluate([10.0])[0])
    assert u2[0, 0] == pytest.approx(1e5 * 5.0 * LPM / np.sqrt(4e5) + 0.4)
    for bad, field in (
        (edit(p, "controller.dp", ...), "controller.dp"),
        (edit(p, "controller.dp", -1.0), "controller.dp"),
        (edit(p, "controller.kappa", 0.0), "controller.kappa"),
        (edit(p, "controller.i_0", 2.0), "controller.i_0"),
        (edit(p, "controller.output", "angle"), "controller.output"),
    ):
        with pytest.raises(InvalidParameter) as err:
            factory.validate(bad, VALVE, 4000.0)
        assert err.value.field == field
    with pytest.raises(InvalidParameter) as err:
        factory.validate(edit(measured, "controller.dp", 1e5), VALVE_DP, 4000.0)
    assert err.value.field == "controller.dp"


def test_reference_per_output_and_per_run_kinds():
    """Nested levels give one trajectory per output (plate tilt); flat lists are shared by all
    outputs even when a time list happens to have n_outputs entries."""
    nested = {
        "reference": {
            "kind": "setpoints",
            "levels": [[0.0, 1.0], [0.0, 2.0, 0.0], [3.0]],
            "transition": [[0.5], [0.2, 0.3], []],
            "hold": 0.1,
        }
    }
    shared = {
        "reference": {"kind": "setpoints", "levels": [0.0, 1.0, 0.0, 2.0], "transition": [0.5, 0.2, 0.3], "hold": 0.1}
    }
    ref = factory.reference([nested, shared], 3)
    t = np.linspace(0.0, 2.0, 81)
    R = ref.evaluate(t)
    expected = [
        Setpoints.build([0.0, 1.0], [0.5], 0.1),
        Setpoints.build([0.0, 2.0, 0.0], [0.2, 0.3], 0.1),
        Setpoints.build([3.0], [], 0.1),
    ]
    for o, tr in enumerate(expected):
        np.testing.assert_array_equal(R[:, 0, o], tr.evaluate(t))
    flat = Setpoints.build([0.0, 1.0, 0.0, 2.0], [0.5, 0.2, 0.3], 0.1).evaluate(t)
    for o in range(3):
        np.testing.assert_array_equal(R[:, 1, o], flat)
    with pytest.raises(InvalidParameter) as err:
        factory.reference([nested], 2)
    assert err.value.field == "reference.levels"
    with pytest.raises(InvalidParameter) as err:
        factory.reference([edit(shared, "reference.amplitude", 1.0)], 1)
    assert err.value.field == "reference.amplitude"


def test_valve_gamma_is_in_paper1_units():
    """γ = 0.4 m³/(A s²) of paper 1 Sec. 5.3 is 0.4 · 60 000 (l/min)/(A s) on the l/min flow signal."""
    p = {"controller": {"kind": "mfc1", "output": "flow", "gamma": 0.4, "k_p": 30.0, "i_min": 0.5},
         "differentiator": {"alpha": 2, "beta": 2, "omega_c": 250.0},
         "reference": {"kind": "setpoints", "levels": [1.0, 5.0, 1.0], "transition": 5.0, "hold": 5.0}}  # fmt: skip
    c, _ = factory.build([p], VALVE, 4000.0)
    assert c.gamma[0, 0] == pytest.approx(24_000.0) and c.k_p[0, 0] == 30.0
    assert c.u_min[0, 0] == 0.5 and c.u_max[0, 0] == 1.01
