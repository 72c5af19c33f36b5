"""Stability overlays and the theory/outcome agreement, against the thesis's closed forms.

(2.41): 0 < k_p < (π/2)·γ/(ρδ); (2.46): a(1 − γ/b) < k_p < a + γ/(bδ)·sqrt(z̃² + (aδ)²) with
z̃ ∈ (π/2, π) solving tan z = −z/(aδ) (computed here with brentq, independently of the module).
"""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure
from scipy.optimize import brentq

from labrunner.analysis.agreement import agreement
from labrunner.analysis.map_data import Axis, Grid
from labrunner.analysis.maps import map_figure
from labrunner.analysis.overlays import Theory, gamma_kp_lines, kp_kd_lines, sweep_lines

A, B, DELAY = 39.44, 108.55, 0.035
MOTOR = {"a": A, "b": B, "rho": B}


def kp_246(gamma: float) -> tuple[float, float]:
    z = brentq(lambda z: math.tan(z) + z / (A * DELAY), math.pi / 2 + 1e-9, math.pi - 1e-9)
    return A * (1 - gamma / B), A + gamma / (B * DELAY) * math.sqrt(z * z + (A * DELAY) ** 2)


def test_gamma_kp_lines_follow_241_and_246():
    theory = Theory("mfc1", DELAY, MOTOR)
    gammas = np.geomspace(1.0, 1e4, 40)
    lines = {line.gid: line for line in gamma_kp_lines(theory, gammas)}
    assert set(lines) == {
        "bound:mfc1-ultralocal:k_p_max",
        "bound:mfc1-motor:k_p_max",
        "bound:mfc1-motor:k_p_min",
        "nominal-gain",
    }
    np.testing.assert_allclose(lines["bound:mfc1-ultralocal:k_p_max"].y, math.pi / 2 * gammas / (B * DELAY), rtol=1e-9)
    np.testing.assert_allclose(lines["bound:mfc1-motor:k_p_max"].y, [kp_246(g)[1] for g in gammas], rtol=1e-6)
    lo = lines["bound:mfc1-motor:k_p_min"].y
    below = gammas < B
    np.testing.assert_allclose(lo[below], [kp_246(g)[0] for g in gammas[below]], rtol=1e-9)
    assert np.isnan(lo[~below]).all()  # a(1 − γ/b) ≤ 0: no positive lower bound to draw on a log axis
    assert lines["nominal-gain"].x == B and lines["nominal-gain"].y is None
    assert lines["bound:mfc1-motor:k_p_min"].linestyle == "--" and lines["bound:mfc1-motor:k_p_max"].linestyle == "-"


def test_ultralocal_only_rig_gets_241_and_nominal_line():
    theory = Theory("mfc1", DELAY, {"rho": 2.0})  # e.g. a valve: no motor model
    gids = {line.gid for line in gamma_kp_lines(theory, np.geomspace(1, 10, 5))}
    assert gids == {"bound:mfc1-ultralocal:k_p_max", "nominal-gain"}
    assert gamma_kp_lines(Theory("open-loop", DELAY, MOTOR), np.geomspace(1, 10, 5))[-1].gid == "nominal-gain"


def test_kp_kd_lines_use_the_corrected_kd_limit():
    theory = Theory("mfc2", DELAY, MOTOR)
    k_ds = np.geomspace(1.0, 300.0, 30)
    lines = {line.gid: line for line in kp_kd_lines(theory, B, k_ds)}
    # corrected ultra-local k_d limit (issue 3): (π/2)·γ/(ρδ), not the printed z̃·sin z̃ form of (2.53)
    assert lines["bound:mfc2-ultralocal:k_d_max"].y == pytest.approx(math.pi / 2 / DELAY)
    assert lines["bound:mfc2-ultralocal:k_d_max"].x is None
    assert {"bound:mfc2-motor:k_p_max", "bound:mfc2-ultralocal:k_p_max", "bound:mfc2-motor:k_d_max"} <= set(lines)
    kp = lines["bound:mfc2-motor:k_p_max"]
    np.testing.assert_allclose(kp.y, k_ds)  # curve over k_d: x = k_p bound, y = k_d
    assert np.isnan(kp.x[k_ds > lines["bound:mfc2-motor:k_d_max"].y]).all()  # no stable k_p above the k_d limit
    assert np.isfinite(kp.x[k_ds < 50]).all() and (kp.x[k_ds < 50] > 0).all()


def test_overlays_drawn_on_the_map_axes():
    theory = Theory("mfc1", DELAY, MOTOR)
    g, kp = np.logspace(0, 4, 5), np.logspace(-1, 3, 5)
    G, K = np.meshgrid(g, kp)
    table = pd.DataFrame(
        {"controller.gamma": G.ravel(), "controller.k_p": K.ravel(), "outcome": "completed", "rms_error": 1.0}
    )
    fig = map_figure(
        Grid.of(table, Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p"), ["rms_error"]),
        "rms_error",
        title="t",
        colour_label="c",
        overlays=gamma_kp_lines(theory, np.geomspace(0.5, 2e4, 50)),
    )
    gids = [line.get_gid() for line in fig.axes[0].get_lines()]
    assert sorted(gids) == sorted(
        ["bound:mfc1-ultralocal:k_p_max", "bound:mfc1-motor:k_p_max", "bound:mfc1-motor:k_p_min", "nominal-gain"]
    )
    assert isinstance(fig, Figure)


def test_sweep_lines_mark_the_246_limits():
    theory = Theory("mfc1", DELAY, MOTOR)
    dense = np.geomspace(0.1, 1000.0, 2000)
    lines = sweep_lines(theory, "k_p", dense, {"gamma": 50.0})
    lo, hi = kp_246(50.0)
    motor = sorted(line.x for line in lines if line.gid == "bound:mfc1-motor:k_p")
    assert motor == pytest.approx([lo, hi], rel=0.01)
    ultra = [line.x for line in lines if line.gid == "bound:mfc1-ultralocal:k_p"]
    assert ultra == pytest.approx([math.pi / 2 * 50.0 / (B * DELAY)], rel=0.01)
    gamma_lines = sweep_lines(theory, "gamma", np.geomspace(1, 1e4, 400), {"k_p": 10.0})
    assert any(line.gid == "nominal-gain" for line in gamma_lines)
    g_lo = B * (1 - 10.0 / A)  # k_p > a(1 − γ/b) ⇔ γ > b(1 − k_p/a)
    assert min(line.x for line in gamma_lines if line.gid.startswith("bound:mfc1-motor")) == pytest.approx(
        g_lo, rel=0.02
    )


def test_agreement_counts_and_margin():
    theory = Theory("mfc1", DELAY, MOTOR)
    gamma = 50.0
    lo, hi = kp_246(gamma)
    rows = [  # (k_p, status, expected: "match" | "false_stable" | "false_unstable" | "excluded" | None)
        (lo * 2, "completed", "match"),
        (hi * 2, "aborted", "match"),
        (lo / 2, "aborted", "match"),
        ((lo * hi) ** 0.5, "no-motion", "match"),  # no motion is a stable loop with a small input
        (hi * 1.5, "completed", "false_unstable"),
        (lo * 3, "aborted", "false_stable"),
        (hi * 1.05, "aborted", "excluded"),
        (lo * 0.95, "completed", "excluded"),
        (lo * 2, "failed", None),
        (lo * 2, "planned", None),
    ]
    table = pd.DataFrame(
        {"controller.gamma": gamma, "controller.k_p": [r[0] for r in rows], "outcome": [r[1] for r in rows]}
    )
    result = agreement(table, lambda row: theory, margin=0.1)
    assert result["case"] == "mfc1-motor"
    assert result["n_match"] == 4 and result["false_unstable"] == 1 and result["false_stable"] == 1
    assert result["n_excluded"] == 2 and result["n_compared"] == 6
    assert result["observed_unstable"] == 3  # the compared aborted runs
    assert result["share"] == pytest.approx(4 / 6)
    wide = agreement(table, lambda row: theory, margin=0.0)
    assert wide["n_excluded"] == 0 and wide["n_compared"] == 8 and wide["observed_unstable"] == 4
    assert agreement(table, lambda row: None)["share"] is None


def test_agreement_of_a_kp_kd_grid_with_fixed_gamma():
    """Second-order case: k_d comes from the grid, γ from the resolved point (gains_of)."""
    theory = Theory("mfc2", DELAY, MOTOR)
    k_d = 20.0
    interval = theory.bounds("mfc2-motor", B, k_d)["k_p"]
    table = pd.DataFrame(
        {
            "controller.k_p": [interval[1] / 3, interval[1] * 3],
            "controller.k_d": k_d,
            "outcome": ["completed", "aborted"],
        }
    )
    result = agreement(
        table,
        lambda row: theory,
        gains_of=lambda row: {"gamma": B, "k_p": row["controller.k_p"], "k_d": row["controller.k_d"]},
    )
    assert result["case"] == "mfc2-motor" and result["share"] == 1.0 and result["n_compared"] == 2
    assert agreement(table, lambda row: theory)["n_compared"] == 0  # without γ nothing can be predicted


def test_lines_that_miss_the_map_say_so_in_the_legend():
    from labrunner.analysis.figures import mark_outside
    from labrunner.analysis.overlays import OverlayLine

    x = Axis("controller.gamma", np.logspace(-2, 1, 4), True, "γ")
    y = Axis("controller.k_p", np.logspace(0, 3, 4), True, "k_p")
    lines = [
        OverlayLine("nominal", 8384.0, None, "white"),
        OverlayLine("inside", 1.0, None, "white"),
        OverlayLine("curve", np.array([1e3, 1e4]), np.array([1e5, 1e6]), "red"),
        OverlayLine("k_d", None, 50.0, "red"),
    ]
    labels = [line.label for line in mark_outside(lines, x, y)]
    assert labels == ["nominal (outside the map)", "inside", "curve (outside the map)", "k_d"]


def test_valve_theory_adds_the_sensor_delay_and_uses_rho_in_the_unit_of_gamma():
    """Paper 1's γ is in m³/(A s²) while the twin's flow is in l/min: the overlay's ρ must be the
    twin's ρ in that unit (rho_si), and the 50 ms flow-sensor delay adds to δ_t in the loop."""
    from labrunner.analysis.context import Theories
    from labrunner.campaign import spec
    from labrunner.rigs import registry

    path = Path(__file__).resolve().parents[1] / "campaigns" / "valve-gamma-kp.toml"
    campaign = spec.from_text(path.read_text(), source_path=path)
    row = {"controller.gamma": 0.4, "controller.k_p": 30.0}
    theory = Theories(campaign)(row)
    constants = registry.load_rig("valve-sim").info.constants
    assert theory.rho == pytest.approx(constants["rho_si"])
    assert theory.dead_time == constants["sensor_delay"] == 0.05
    assert theory.delay == pytest.approx(31 / 4000 + 0.05)  # δ_t of No. 1 (α = β = 2, ω_c = 250) at 4 kHz
    assert "sensor delay" in theory.delay_note()


def test_kp_kd_map_of_the_shipped_campaign_carries_the_corrected_bounds():
    """campaigns/dcmotor-angle-kp-kd.toml (thesis Fig. 3.14, γ_θ = b from [derived]): the overlay
    lines of its map, checked against the spectral-abscissa solver (an independent method) and
    drawn as artists on the map."""
    from labrunner import stability
    from labrunner.analysis.context import Theories
    from labrunner.analysis.figures import axis_of, grid_forms, map_overlays
    from labrunner.campaign import spec

    path = Path(__file__).resolve().parents[1] / "campaigns" / "dcmotor-angle-kp-kd.toml"
    campaign = spec.from_text(path.read_text(), source_path=path)
    points, _ = spec.plan(campaign)
    table = pd.DataFrame([{**p.parameters, "outcome": "completed", "rms_error": 1.0} for p in points])
    table.loc[table["controller.k_d"] > 150, "outcome"] = "aborted"
    forms = grid_forms(campaign)
    assert forms == {"controller.k_p": "log10", "controller.k_d": "log10"}
    x, y = (axis_of(table, k, {}, forms[k]) for k in ("controller.k_p", "controller.k_d"))
    lines, note = map_overlays(table, x, y, Theories(campaign))
    assert note == "δ_t = 35 ms, γ = 108.55"
    by_gid = {line.gid: line for line in lines}
    assert set(by_gid) == {
        "bound:mfc2-ultralocal:k_p_max",
        "bound:mfc2-ultralocal:k_d_max",
        "bound:mfc2-motor:k_p_max",
        "bound:mfc2-motor:k_d_max",
    }
    kp_max = by_gid["bound:mfc2-motor:k_p_max"]
    assert np.isnan(kp_max.x[kp_max.y > 112.3]).all()  # no stable k_p above the k_d limit
    for i in (0, 60, 120, 150):  # k_d ≈ 0.75, 5.1, 34, 89 1/s
        numeric = stability.bounds("mfc2-motor", gamma=B, delay=DELAY, a=A, b=B, k_d=float(kp_max.y[i]), numeric=True)
        assert kp_max.x[i] == pytest.approx(numeric["numeric"]["k_p"][1], rel=1e-3)
    numeric = stability.bounds("mfc2-motor", gamma=B, delay=DELAY, a=A, b=B, k_d=10.0, numeric=True)["numeric"]
    assert by_gid["bound:mfc2-motor:k_d_max"].y == pytest.approx(numeric["k_d"][1], rel=1e-3)
    fig = map_figure(Grid.of(table, x, y, ["rms_error"]), "rms_error", title="t", colour_label="c", overlays=lines)
    ax = fig.axes[0]
    assert ax.get_xscale() == ax.get_yscale() == "log"
    drawn = {line.get_gid(): line for line in ax.get_lines()}
    assert set(drawn) == set(by_gid)
    np.testing.assert_allclose(drawn["bound:mfc2-motor:k_p_max"].get_xdata(), kp_max.x)
    np.testing.assert_allclose(drawn["bound:mfc2-ultralocal:k_d_max"].get_ydata(), [math.pi / 2 / DELAY] * 2)
    assert {c.get_label() for c in ax.collections if c.get_label().startswith(("aborted", "completed"))} == {
        "aborted by the safety routine",
        "completed",
    }


def test_map_axes_follow_the_grid_form():
    """A log10 axis is drawn on a log scale even over less than a decade, a linspace axis linearly
    even when its values span decades; listed values are judged by their spacing."""
    from labrunner.analysis.figures import axis_of

    table = pd.DataFrame({"g": [100.0, 177.8, 316.2], "k": [1.0, 10.0, 100.0]})
    assert axis_of(table, "g", {}, "log10").log and not axis_of(table, "g", {}, "values").log
    assert not axis_of(table, "k", {}, "linspace").log and axis_of(table, "k", {}, "values").log


@pytest.mark.parametrize(
    ("kind", "case"), [("mfc1", "mfc1-motor"), ("mfc1", "mfc1-ultralocal"), ("mfc2", "mfc2-motor")]
)
def test_k_p_limits_equal_the_bounds_point_by_point(kind, case):
    """The vectorised limits (one bounds() per distinct (γ, k_d)) are bounds()' own numbers, also
    with repeated values and where no k_p is stable (NaN)."""
    theory = Theory(kind, DELAY, MOTOR)
    gammas = np.array([[1.0, 50.0, 108.55], [50.0, 400.0, 1.0]])
    k_ds = None if kind == "mfc1" else np.array([[20.0, 20.0, 5.0], [20.0, 60.0, 20.0]])
    lo, hi = theory.k_p_limits(case, gammas, k_ds)
    assert lo.shape == hi.shape == gammas.shape
    for idx in np.ndindex(gammas.shape):
        found = theory.bounds(case, gammas[idx], None if k_ds is None else k_ds[idx])["k_p"]
        expected = (np.nan, np.nan) if found is None else tuple(found)
        np.testing.assert_array_equal([lo[idx], hi[idx]], expected)
    assert kind == "mfc1" or np.isnan(lo).any()  # k_d = 60 lies outside the corrected k_d range


def test_parameter_records_are_the_dotted_columns_and_the_distinct_settings():
    from labrunner.analysis.context import parameter_records

    table = pd.DataFrame(
        {
            "controller.gamma": [1.0, 2.0, 1.0, 2.0],
            "controller.k_p": [5.0, 5.0, 6.0, 6.0],
            "differentiator.alpha": [4.0, 4.0, 6.0, 6.0],
            "reference.law": ["step", "step", "step", None],
            "rms_error": [0.1, 0.2, 0.3, 0.4],
        }
    )
    plain = parameter_records(table)
    assert plain == [{k: v for k, v in r.items() if k != "rms_error"} for r in table.to_dict("records")]
    settings = parameter_records(table, settings=True)
    assert len(settings) == 3 and all(set(r) == {"differentiator.alpha", "reference.law"} for r in settings)
    assert parameter_records(table[["controller.gamma", "controller.k_p"]], settings=True) == [{}]
    assert parameter_records(table.iloc[:0], settings=True) == []
