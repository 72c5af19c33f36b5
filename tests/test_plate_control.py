"""Closed loops on the plate twin: paper 2's MBC (Sec. 3.1, 4.2) and MFC (Sec. 3.2, 4.1) lift and track.

References: the physics (the hover current carries a quarter of the weight per magnet, eq. (2),
(12); f_v = η + g ≈ g, eq. (13)), the paper's parameters (k_p = 5000, k_d = 195, γ_v = 1,
α = β = 4, ω_c = 840 rad/s) and its observations (Remark 9: the 942 rad/s resonance must be
suppressed; Table 3: tracking errors of a few µm).
"""

import numpy as np
import pytest
from plate_loop import FS, closed_loop
from scipy import signal

from labrunner.control.factory import build, differentiators
from labrunner.control.plate import PlateMFC
from labrunner.errors import InvalidParameter
from labrunner.plate_geometry import PlateGeometry
from labrunner.rigs.sim.plate import PlateTwin

SHORT = {"kind": "setpoints", "levels": [5.5e-3, 2e-3], "transition": 0.6, "hold": [0.0, 0.4]}
MFC = {"kind": "plate-mfc", "input": "v", "gamma": 1.0, "k_p": 5000.0, "k_d": 195.0}
DIFF = {"alpha": 4, "omega_c": 840.0}
GEO = PlateGeometry()
I_HOVER = 250 * 2e-3 * np.sqrt(GEO.m * GEO.g / 4)  # eq. (12) with d = λ^(-1/2) h at 2 mm


def check_hover(out, rms_um=5.0):
    hold = out["t"] > 0.75
    e = out["y"][hold][:, :, :3] - out["r"][hold]
    assert np.sqrt(np.mean(e**2)) < rms_um * 1e-6
    np.testing.assert_allclose(out["u"][hold].mean(axis=0), I_HOVER, rtol=0.03)


@pytest.fixture(scope="module")
def mbc_lift():
    return closed_loop({"controller": {"kind": "plate-mbc"}, "reference": SHORT})


def test_mbc_lifts_and_hovers(mbc_lift):
    check_hover(mbc_lift)
    # f_hat of the MBC is η̂ + g: at hover only gravity (and the plate's sag) acts
    np.testing.assert_allclose(mbc_lift["f_hat"][mbc_lift["t"] > 0.75].mean(axis=0), GEO.g, rtol=0.02)


def test_resonance_visible_in_measurement(mbc_lift):
    """Paper 2 Remark 9: the plate's resonance near 942 rad/s shows in the hovering plate's sensor signals."""
    hold = mbc_lift["t"] > 0.7
    y1 = mbc_lift["y"][hold, 0, 0]
    f, P = signal.welch(y1 - y1.mean(), fs=FS, nperseg=4096)
    w = 2 * np.pi * f
    band = (w > 600) & (w < 3000)
    peak = w[band][np.argmax(P[band])]
    assert peak == pytest.approx(942.0, rel=0.05)
    assert P[band].max() > 10 * np.median(P[(w > 1500) & (w < 5000)])


def test_mfc_lifts_and_hovers():
    out = closed_loop({"controller": MFC, "differentiator": DIFF, "reference": SHORT})
    check_hover(out)
    # eq. (13) with γ_v = 1: f_v = η + g, and η ≈ 0 at hover on the nominal plate
    np.testing.assert_allclose(out["f_hat"][out["t"] > 0.75].mean(axis=0), GEO.g, rtol=0.02)


def test_mfc_without_notch_is_unstable():
    """Paper 2 Remark 9: without the notch the resonance destabilises the loop (the plate hits a stop)."""
    out = closed_loop(
        {"controller": {**MFC, "notch_omega": 0.0}, "differentiator": DIFF, "reference": SHORT}, seconds=0.5
    )
    assert out["y"][:, 0, :3].min() < 0.8e-3


@pytest.mark.slow
@pytest.mark.parametrize(
    "controller",
    [
        {**MFC, "input": "force", "gamma": 1.0},  # γ_F = 1 1/kg (Sec. 4.1)
        {**MFC, "input": "u", "gamma": 1.6e-5},  # γ_u = λ γ_F = 1.6·10⁻⁵ m³/(A² s²)
        {**MFC, "input": "current", "gamma": 0.04},  # γ_i,0 = 40 with y in mm, 0.04 in SI
    ],
    ids=["force", "u", "current"],
)
def test_mfc_input_variants_lift_and_hover(controller):
    out = closed_loop({"controller": controller, "differentiator": DIFF, "reference": SHORT})
    check_hover(out, rms_um=10.0)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["plate-mbc", "plate-mfc"])
def test_paper_lift_trajectory(kind):
    """Sec. 4.1 / 4.3.1: 5.5 → 2 mm in 2 s, then 2 → 5 → 2 mm (0.5 s transitions, 0.2 s holds)."""
    point = (
        {"controller": {"kind": "plate-mbc"}} if kind == "plate-mbc" else {"controller": MFC, "differentiator": DIFF}
    )
    out = closed_loop({**point, "reference": {"kind": "lift"}}, seconds=4.2)
    e = out["y"][:, 0, :3] - out["r"][:, 0]
    moving = out["t"] > 2.5
    assert np.abs(e[moving]).max() < 100e-6  # tracks the 3 mm moves within 0.1 mm (delays of the filters)
    assert np.abs(e[-1000:]).mean() < 5e-6  # and settles at 2 mm
    assert out["y"][:, 0, :3].min() > 0.8e-3  # never near the yokes


@pytest.mark.slow
def test_tilt_with_force_input_decouples():
    """Sec. 4.3.2, Fig. 12: the force-input MFC (17) tilts the plate with three individually timed
    transitions, decoupled only through f̂; at rest f̂_F,k = γ_F F̃_k carries a quarter of the weight."""
    controller = {**MFC, "input": "force", "gamma": 1.0}
    out = closed_loop(
        {"controller": controller, "differentiator": DIFF, "reference": {"kind": "tilt", "lift": 0.8, "settle": 0.3}}
    )
    e = out["y"][:, 0, :3] - out["r"][:, 0]
    after_lift = out["t"] > 1.1
    assert np.sqrt(np.mean(e[after_lift] ** 2, axis=0)).max() < 10e-6
    tilted = np.argmin(np.abs(out["t"] - 2.0))  # all three points at their targets
    np.testing.assert_allclose(out["y"][tilted, 0, :3], [2.5e-3, 1.5e-3, 2.5e-3], atol=5e-6)
    np.testing.assert_allclose(out["f_hat"][-1000:, 0].mean(axis=0), GEO.m * GEO.g / 4, rtol=0.03)


def test_mixed_input_batch_equals_single_input_batches():
    """Runs differing only in ``controller.input`` share a batch (factory.PER_RUN_CHOICES): each row's
    closed loop is bit for bit that of the same run in a batch of its input alone of the same size."""
    gains = {"v": 1.0, "force": 1.0, "u": 1.6e-5, "current": 0.04}  # paper 2 Sec. 4.1
    points = [
        {"controller": {**MFC, "input": x, "gamma": g}, "differentiator": DIFF, "reference": SHORT}
        for x, g in gains.items()
    ]
    mixed = closed_loop(points, seconds=0.3)
    for b, point in enumerate(points):
        alone = closed_loop([point] * len(points), seconds=0.3)
        for name in ("u", "y", "f_hat"):
            np.testing.assert_array_equal(mixed[name][:, b], alone[name][:, b], err_msg=point["controller"]["input"])
    assert np.ptp(mixed["u"][-1, :, 0]) > 1e-3  # the four laws do drive the plate differently


def test_batch_gains_and_validation():
    info = PlateTwin.nominal_info("plate-sim", "", {})
    points = [
        {"controller": {**MFC, "k_p": kp}, "differentiator": DIFF, "reference": {"kind": "lift", "delay": True}}
        for kp in (4000.0, 5000.0)
    ]
    controller, ref = build(points, info, FS)
    assert isinstance(controller, PlateMFC) and controller.k_p[:, 0].tolist() == [4000.0, 5000.0]
    r = ref.evaluate(np.array([0.0]))[0]
    np.testing.assert_allclose(r[:, :, 0], 5.5e-3)  # the lift starts at the rig's rest gap
    bad = [
        ({**MFC, "input": "flux"}, "controller.input"),
        ({**MFC, "weights": [0.5, 0.5, 0.0]}, "controller.weights"),  # v uses the pseudo-inverse
        ({**MFC, "input": "force", "weights": [0.5, 0.6, 0.0]}, "controller.weights"),
        ({**MFC, "gamma": 0.0}, "controller.gamma"),
        ({**MFC, "i_max": 9.0}, "controller.i_max"),
        ({**MFC, "kp": 1.0}, "controller.kp"),
        ({**MFC, "y_min": 1e-3}, "controller.y_min"),  # γ_i(y) is the current input's
    ]
    weights = [0.2, 0.4, 0.4]  # a mixed batch: weights and y_min on the rows whose law uses them
    mixed = [{**MFC}, {**MFC, "input": "force", "weights": weights}, {**MFC, "input": "current", "gamma": 0.04,
             "weights": weights, "y_min": 1e-3}]  # fmt: skip
    lift = {"differentiator": DIFF, "reference": {"kind": "lift"}}
    controller, _ = build([{"controller": c, **lift} for c in mixed], info, FS)
    assert controller.inputs == ("v", "force", "current") and controller.y_min[:, 0].tolist() == [8e-4, 8e-4, 1e-3]
    with pytest.raises(InvalidParameter, match="controller.weights"):  # force's weights, current's default
        build([{"controller": c, **lift} for c in (mixed[1], {**mixed[2], "weights": [0.0, 0.5, 0.5]})], info, FS)
    for controller_section, field in bad:
        with pytest.raises(InvalidParameter, match=field):
            build([{"controller": controller_section, "differentiator": DIFF, "reference": {"kind": "lift"}}], info, FS)
    with pytest.raises(InvalidParameter, match="reference.targets"):
        build(
            [{"controller": MFC, "differentiator": DIFF, "reference": {"kind": "tilt", "targets": [2e-3, 3e-3]}}],
            info,
            FS,
        )


def _drive(points, ticks=60, seed=3):
    """Step a batch controller through a synthetic measurement around 3 mm; record u, y, r and estimates."""
    info = PlateTwin.nominal_info("plate-sim", "", {})
    controller, _ = build(points, info, FS)
    B = len(points)
    rng = np.random.default_rng(seed)
    y = np.full((B, 4), 3e-3)
    controller.reset(y)
    r = np.zeros((B, 3, 4))
    r[:, :, 0], r[:, :, 2] = 3e-3, -10.0  # pull up: the law demands positive forces
    log = []
    for _ in range(ticks):
        y = 3e-3 + 2e-6 * rng.standard_normal((B, 4))
        u = controller.step(y, r)
        est = {k: v.copy() for k, v in controller.estimates.items()}
        log.append((y, u, est))
    return controller, r, log


@pytest.mark.parametrize("variant", ["v", "force", "u", "current"])
def test_law_reconstructed_from_estimates(variant):
    """u from the controller equals eqs. (14)/(17)/(19)/(21) with (11)/(18) and (12), rebuilt from f̂, ê, ê̇."""
    gamma = {"v": 1.0, "force": 0.9, "u": 1.5e-5, "current": 0.04}[variant]
    point = {
        "controller": {**MFC, "input": variant, "gamma": gamma},
        "differentiator": DIFF,
        "reference": {"kind": "lift"},
    }
    controller, r, log = _drive([point])
    checked = 0
    for y, u, est in log:
        if not np.all((u > 0) & (u < 8)):
            continue  # saturated: the law is clipped
        checked += 1
        w = r[:, :, 2] - 5000 * est["e_hat"] - 195 * est["de_hat"] - est["f_hat"]
        h = GEO.gaps_from_sensors(y)
        forces = (u / (250 * h)) ** 2
        if variant == "v":
            np.testing.assert_allclose(GEO.input_from_forces(forces), w / gamma, rtol=1e-9)
            np.testing.assert_allclose(forces, GEO.forces_pinv(w / gamma), rtol=1e-9)
            continue
        x = {"force": forces, "u": (u / h) ** 2, "current": u}[variant]
        expected = -w / gamma * (y[:, :3] if variant == "current" else 1.0)
        np.testing.assert_allclose(x[:, :3], expected, rtol=1e-9)
        np.testing.assert_allclose(x[:, 3], 0.5 * (x[:, 1] + x[:, 2]), rtol=1e-12)  # F_d,4 = (F_2 + F_3)/2
    assert checked > 10


@pytest.mark.parametrize("kind", ["plate-mfc", "plate-mbc"])
def test_batch_equals_single_runs(kind):
    if kind == "plate-mfc":
        points = [{"controller": {**MFC, "k_p": kp, "k_d": kd}, "differentiator": {"alpha": a, "omega_c": 840.0}, "reference": {"kind": "lift"}}
                  for kp, kd, a in [(4000.0, 150.0, 4), (5000.0, 195.0, 3), (6000.0, 220.0, 4)]]  # fmt: skip
    else:
        points = [{"controller": {"kind": "plate-mbc", "c_p": cp, "observer_poles": poles}, "reference": {"kind": "lift"}}
                  for cp, poles in [(4000.0, [700, 720, 740]), (5000.0, [820, 840, 860]), (6000.0, [900, 910, 920])]]  # fmt: skip
    _, _, batch = _drive(points)
    for b, point in enumerate(points):
        # drive a single run with run b's samples of the batch
        info = PlateTwin.nominal_info("plate-sim", "", {})
        controller, _ = build([point], info, FS)
        controller.reset(np.full((1, 4), 3e-3))
        r = np.zeros((1, 3, 4))
        r[:, :, 0], r[:, :, 2] = 3e-3, -10.0
        for y, u, _ in batch:
            np.testing.assert_allclose(controller.step(y[b : b + 1], r), u[b : b + 1], rtol=1e-12, atol=1e-12)


def test_estimator_uses_the_applied_saturated_currents():
    """Eq. (24b)/(25) with the *applied* input (thesis Sec. 3.3 on the hardware): f̂_v[k] =
    Σ ŵ₂ y[k−1−j] − γ_v Σ ŵ₀ v[k−1−j], v[k] = P⁻¹B f(i_sat[k], h[k]) (eqs. (2), (4), (5)), rebuilt
    from the logged measurements and the saturated currents; with the law's unsaturated currents
    the same sum misses the controller's f̂. Notch off, so f̂ sees the raw measurement."""
    point = {
        "controller": {**MFC, "notch_omega": 0.0, "i_max": 2.7},
        "differentiator": DIFF,
        "reference": {"kind": "lift"},
    }
    _, r, log = _drive([point], ticks=120)
    d = differentiators([point], FS, 2)[0]
    w2, w0, n = d.weights(2), d.weights(0), d.n_s
    Y = np.array([y[0, :3] for y, _, _ in log])
    U = np.array([u[0] for _, u, _ in log])
    assert (U == 2.7).sum() > 20 and (U < 2.7).any()  # saturated on many ticks, not on all

    def v_of(currents, y):
        return GEO.input_from_forces((currents / (250 * GEO.gaps_from_sensors(y))) ** 2)

    unsat = [
        GEO.forces_pinv(r[0, :, 2] - 5000 * e["e_hat"][0] - 195 * e["de_hat"][0] - e["f_hat"][0]) for _, _, e in log
    ]
    unsat = np.array([250 * GEO.gaps_from_sensors(y) * np.sqrt(np.maximum(f, 0.0)) for y, f in zip(Y, unsat)])
    y_h = np.vstack([np.full((n + 1, 3), 3e-3), Y])  # the stationary past of reset
    for currents, expect_match in ((U, True), (unsat, False)):
        v_h = np.vstack([np.zeros((n + 1, 3)), v_of(currents, Y)])  # at rest: no current, v = 0
        errors = []
        for k, (_, _, est) in enumerate(log):
            past = n + k - np.arange(n)  # rows of y[k−1−j], v[k−1−j]
            f_hat = w2 @ y_h[past] - 1.0 * (w0 @ v_h[past])
            errors.append(np.abs(f_hat - est["f_hat"][0]).max())
        if expect_match:
            assert max(errors) < 1e-9 * GEO.g
        else:
            assert max(errors) > 1e-4 * GEO.g  # 10⁵ times the rounding of the match
