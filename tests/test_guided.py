"""Guided procedures against hand-computed walks on small ladders (a fake plant, in-process).

Each fake plant is a rule in the spirit of thesis Sec. 3.5.1: only the ratio k_p/γ decides whether
the safety routine trips (Fig. 3.11), a tiny ratio leaves the load at rest (no-motion), and the
RMS error falls towards the stability edge. The expected step counts are worked out in the
comments from the ladder γ_i = 10^(log10 γ̃ − i/per_decade); the tests compare literal numbers.
"""

from __future__ import annotations

import math

import pytest
from test_guided_support import write_campaign

from labrunner.campaign import guided, spec
from labrunner.campaign.guided import Ladder, advance, drive
from labrunner.campaign.guided_walks import GAMMA, KD, KP, Guideline2, Guideline3, Polack, ultralocal_start
from labrunner.errors import InvalidParameter


def ratio_plant(trip: float, still: float = 0.005):
    """k_p/γ > trip: aborted; < still: no-motion; else completed with RMS 1/(1 + 10 k_p/γ)."""

    def oracle(points):
        out = []
        for p in points:
            r = p[KP] / p[GAMMA]
            status = "aborted" if r > trip else "no-motion" if r < still else "completed"
            out.append({"status": status, "rms_error": 1.0 / (1.0 + 10.0 * r)})
        return out

    return oracle


def g2(**kw) -> Guideline2:
    args = dict(case=1, method="walk", gamma_start=1000.0, kp_start=1.0, gamma_stop=1.0, per_decade=4, rms_target=None)
    return Guideline2(**(args | kw))


def gammas(walk):
    return [round(math.log10(s.observation.params[GAMMA]), 6) for s in walk]


def test_ladder_hits_the_thesis_values():
    # thesis Sec. 3.5.3: from 10⁶ in 1/16-decade steps, step 54 is γ = 421.69 and k_p = 0.1·10⁶/γ = 237.13
    values = Ladder(1e6, 1.0, 16).values()
    assert len(values) == 97
    assert values[54] == pytest.approx(421.69, abs=0.01)
    assert 0.1 * 1e6 / values[54] == pytest.approx(237.13, abs=0.01)
    assert Ladder(0.1, 100.0, 16).values()[40] == pytest.approx(31.62, abs=0.01)  # Polack's k_p after 40 steps


def test_guideline2_walk_stops_at_the_first_trip_and_keeps_the_best_run():
    # γ_i = 10^(3 − i/4), k_p = 1000/γ, k_p/γ = 1000/γ²; trips when > 1.5, i.e. γ < 25.8: first at
    # i = 7 (γ = 17.8); 8 runs; i = 0, 1 (ratio 0.001, 0.0032) do not move; best: i = 6 (γ = 31.6)
    end = drive(g2(), "t", ratio_plant(1.5))
    assert end.runs == 8 and end.result.reason == "tripped"
    assert [s.observation.status for s in end.walk][:3] == ["no-motion", "no-motion", "completed"]
    assert end.result.chosen.params[GAMMA] == pytest.approx(10**1.5)
    assert end.result.chosen.params[KP] == pytest.approx(1000.0 / 10**1.5)
    assert gammas(end.walk) == [3 - i / 4 for i in range(8)]


def test_guideline2_walk_stops_at_the_rms_target():
    # RMS = 1/(1 + 10·1000/γ²) ≤ 0.45 ⇔ γ ≤ 90.4: first at i = 5 (γ = 56.2); 6 runs, no trip
    end = drive(g2(rms_target=0.45), "t", ratio_plant(1.5))
    assert (end.runs, end.result.reason) == (6, "target")
    assert end.result.chosen.params[GAMMA] == pytest.approx(10**1.75)


def test_guideline2_walk_ends_at_the_end_of_the_ladder():
    end = drive(g2(gamma_stop=100.0), "t", ratio_plant(1.5))  # 10³ … 10² never trips: 5 runs
    assert (end.runs, end.result.reason) == (5, "end of range")
    assert end.result.chosen.params[GAMMA] == pytest.approx(100.0)


def test_guideline2_bisection_finds_the_walks_choice_in_fewer_runs():
    # indices 0 … 12; runs 0 (no stop), 12 (trip), 6 (ok) → [6, 12], 9 (trip), 7 (trip) → [6, 7]: 5 runs, i = 6
    end = drive(g2(method="bisect"), "t", ratio_plant(1.5))
    assert gammas(end.walk) == [3 - i / 4 for i in (0, 12, 6, 9, 7)]
    assert end.result.reason == "tripped" and end.result.chosen.params[GAMMA] == pytest.approx(10**1.5)
    # with the target (stop for i ≥ 5): 0, 12, 6 (stop), 3, 4, 5 (stop) → i = 5 as the walk
    end = drive(g2(method="bisect", rms_target=0.45), "t", ratio_plant(1.5))
    assert gammas(end.walk) == [3 - i / 4 for i in (0, 12, 6, 3, 4, 5)]
    assert end.result.reason == "target" and end.result.chosen.params[GAMMA] == pytest.approx(10**1.75)
    assert g2(method="bisect").max_runs() == 2 + math.ceil(math.log2(12))


def test_a_failed_run_or_a_tripped_start_stops_the_procedure():
    end = drive(g2(), "t", lambda pts: [{"status": "failed"} for _ in pts])
    assert (end.runs, end.result.reason, end.result.chosen) == (1, "failed", None)
    end = drive(g2(method="bisect"), "t", ratio_plant(1e-9, still=0.0))
    assert (end.runs, end.result.reason, end.result.chosen) == (1, "start trips", None)


def test_guideline2_case2_line_from_rho_and_kappa(tmp_path):
    # ρ = 10, κ = 10, δ = 0.01 s: γ̃ = κρ = 100, k̃_p = πκ/(2δ) = 1570.8, k_p(γ) = πκ²ρ/(2δγ); γ ∈ [ρ, κρ]
    path = write_campaign(
        tmp_path,
        guided={"procedure": "guideline2", "case": 2, "rho": 10.0, "kappa": 10.0, "delay": 0.01, "per_decade": 4},
    )
    proc = spec.load(path).guided
    line = proc.line()
    assert [p[GAMMA] for p in line] == pytest.approx([10 ** (2 - i / 4) for i in range(5)])
    assert line[0][KP] == pytest.approx(math.pi * 10 / 0.02)
    assert all(p[KP] == pytest.approx(math.pi * 100 * 10 / (0.02 * p[GAMMA])) for p in line)
    # k_p/γ = 157079.6/γ² > 50 ⇔ γ < 56.05: trips at i = 2 (γ = 31.6); 3 runs; chosen i = 1
    end = drive(proc, "t", ratio_plant(50.0, still=0.0))
    assert (end.runs, end.result.reason) == (3, "tripped")
    assert end.result.chosen.params[GAMMA] == pytest.approx(10**1.75)


def feed_forward_plant(points):
    """k_p = 0: trips for γ < 20, RMS 0.5 + γ/1000; k_p > 0: trips for k_p/γ > 1.5, RMS minimal at k_p = 10."""
    out = []
    for p in points:
        g, kp = p[GAMMA], p[KP]
        if kp == 0.0:
            out.append({"status": "aborted" if g < 20.0 else "completed", "rms_error": 0.5 + g / 1000.0})
        else:
            out.append(
                {
                    "status": "aborted" if kp / g > 1.5 else "completed",
                    "rms_error": 0.2 + 0.1 * abs(math.log10(kp) - 1.0),
                }
            )
    return out


def polack(**kw) -> Polack:
    args = dict(
        gamma_start=1000.0,
        gamma_stop=1.0,
        kp_start=0.1,
        kp_stop=1000.0,
        per_decade=4,
        back_off=0,
        rms_target=None,
        patience=None,
    )
    return Polack(**(args | kw))


def test_polack_feed_forward_then_feedback():
    # feed-forward: γ_i = 10^(3 − i/4) < 20 first at i = 7: 8 runs; best completed i = 6 (γ = 31.6).
    # feedback at γ = 31.6: k_j = 10^(−1 + j/4); k/γ > 1.5 ⇔ k > 47.4, first at j = 11: 12 runs;
    # RMS minimal at j = 8 (k_p = 10). 20 runs in all.
    end = drive(polack(), "t", feed_forward_plant)
    counts = end.stage_counts()
    assert [v["runs"] for v in counts.values()] == [8, 12] and end.runs == 20
    assert all(s.observation.params[KP] == 0.0 for s in end.walk[:8])
    assert end.result.reason == "tripped"
    assert end.result.chosen.params[GAMMA] == pytest.approx(10**1.5)
    assert end.result.chosen.params[KP] == pytest.approx(10.0)
    # patience 2: RMS rises at j = 9, 10 → stop at j = 10 (11 runs); back_off 1: γ = 10^1.75
    end = drive(polack(patience=2, back_off=1), "t", feed_forward_plant)
    assert [v["runs"] for v in end.stage_counts().values()] == [8, 11]
    assert end.result.reason == "rising" and end.result.detail["gamma"] == pytest.approx(10**1.75)
    assert end.result.chosen.params[KP] == pytest.approx(10.0)


def test_polack_thesis_back_off_passes_over_an_oscillating_best_gamma():
    """Thesis Fig. 3.22: the smallest-RMS feed-forward γ oscillated, so the next best was taken."""

    def plant(points):  # feed_forward_plant, with the runs at γ < 40 flagged oscillating (still completed)
        out = feed_forward_plant(points)
        return [{**o, "oscillating": float(p[KP] == 0.0 and 20.0 <= p[GAMMA] < 40.0)} for p, o in zip(points, out)]

    # feed-forward: best completed γ = 10^1.5 = 31.6 is flagged; the best calm one is 10^1.75 = 56.2
    end = drive(polack(back_off=None), "t", plant)
    assert end.result.detail["gamma"] == pytest.approx(10**1.75)
    # without the flag the rule keeps the best γ; back_off = 0 keeps it even when flagged
    assert drive(polack(back_off=None), "t", feed_forward_plant).result.detail["gamma"] == pytest.approx(10**1.5)
    assert drive(polack(back_off=0), "t", plant).result.detail["gamma"] == pytest.approx(10**1.5)


def test_guideline3_start_is_the_top_of_the_ultralocal_set():
    from labrunner.stability import bounds

    kp, kd = ultralocal_start(100.0, 0.02)
    top = bounds("mfc2-ultralocal", gamma=100.0, delay=0.02, rho=100.0, k_d=kd)["k_p"][1]
    assert kp == pytest.approx(top)
    for other in (0.9 * kd, 1.1 * kd):  # a maximum over k_d
        assert bounds("mfc2-ultralocal", gamma=100.0, delay=0.02, rho=100.0, k_d=other)["k_p"][1] < kp


def test_guideline3_raises_k_d_backs_off_then_raises_k_p():
    # k_d,i = 10·10^(i/4) trips for k_d > 40 (i = 3): 4 runs; back off one: k_d = 10^1.5.
    # step 4 starts at (k̃_p, k_d,2), run in step 3 already; k_p,j = 40π·10^(j/4) trips for
    # k_p > 800 (j = 4): 5 steps, 4 new runs; RMS 1/(k_p k_d) → chosen j = 3. 8 runs.
    proc = Guideline3(
        rho=5.0,
        kp_start=40.0 * math.pi,
        kd_start=10.0,
        kd_stop=1e4,
        kp_stop=1e5,
        per_decade=4,
        kd_back_off=1,
        rms_target=None,
    )

    def plant(points):
        return [
            {"status": "aborted" if p[KD] > 40.0 or p[KP] > 800.0 else "completed", "rms_error": 1.0 / (p[KP] * p[KD])}
            for p in points
        ]

    end = drive(proc, "t", plant)
    assert list(end.stage_counts().values()) == [{"steps": 4, "runs": 4}, {"steps": 5, "runs": 4}]
    assert end.runs == 8 and end.result.detail["k_d"] == pytest.approx(10**1.5)
    assert end.result.chosen.params[KP] == pytest.approx(40.0 * math.pi * 10**0.75)
    assert all(s.observation.params[GAMMA] == 5.0 for s in end.walk)


def test_decisions_are_a_pure_function_of_the_outcomes():
    # replaying any prefix of the outcomes proposes exactly the next point of the walk
    oracle = feed_forward_plant
    end = drive(polack(), "t", oracle)
    known = {}
    for step in end.walk:
        nxt = advance(polack(), "t", known)
        assert nxt.next == (dict(step.observation.params),) and nxt.result is None
        assert advance(polack(), "t", known) == nxt
        known[step.observation.id] = step.observation
    assert advance(polack(), "t", known).result == end.result


def test_guided_section_errors_name_the_key(tmp_path):
    def load(**table):
        return spec.load(write_campaign(tmp_path, guided={"procedure": "guideline2", **table}))

    with pytest.raises(InvalidParameter, match=r"guided\.gamma_start: is required"):
        load(gamma_stop=1.0)
    with pytest.raises(InvalidParameter, match=r"guided\.gamma_stop: must be < the start 1000"):
        load(gamma_start=1000.0, gamma_stop=2000.0)
    with pytest.raises(InvalidParameter, match=r"guided\.kappa: must be > 1"):
        load(case=2, rho=1.0, kappa=0.5)
    with pytest.raises(InvalidParameter, match=r"guided\.speed: unknown key"):
        load(gamma_start=1000.0, gamma_stop=1.0, speed=2)
    with pytest.raises(InvalidParameter, match=r"guided\.procedure: must be one of guideline2"):
        spec.load(write_campaign(tmp_path, guided={"procedure": "simplex"}))
    with pytest.raises(InvalidParameter, match=r"controller\.kind: procedure guideline3 tunes mfc2"):
        spec.load(
            write_campaign(tmp_path, guided={"procedure": "guideline3", "rho": 1.0, "kd_stop": 1e3, "kp_stop": 1e5})
        )
    with pytest.raises(InvalidParameter, match=r"guided: a campaign has either \[grid\]"):
        spec.load(
            write_campaign(tmp_path, guided={"procedure": "guideline2"}, grid={"controller.k_p": {"values": [1.0]}})
        )
    path = write_campaign(
        tmp_path, guided={"procedure": "polack", "gamma_start": 1e3, "gamma_stop": 1.0, "kp_stop": 10.0}
    )
    path.write_text(path.read_text() + '\n[derived]\n"controller.k_p" = "0.1 * controller.gamma"\n')
    with pytest.raises(InvalidParameter, match=r'derived\."controller\.k_p": is set by the polack procedure'):
        spec.load(path)
    assert isinstance(load(gamma_start=1000.0, gamma_stop=1.0).guided, guided.Procedure)


def test_guidelines_stop_where_the_loop_starts_oscillating_and_guideline3_backs_off_to_a_calm_k_d():
    """Guideline 2 Step 3 / Guideline 3 Step 4: "until either the controlled system starts oscillating or
    the tracking error is appropriately small"; Guideline 3 Step 3: "reduce it such that no oscillations
    occur". The detector's flag is the oscillation (runs still complete)."""
    # Guideline 2 along k_p = 1000/γ, γ = 10^(3 − i/4): the runs at k_p/γ > 1 oscillate (from i = 3, γ = 177.8)
    proc = Guideline2(1, "walk", 1000.0, 1.0, 1.0, 4, None)

    def ratio(points):
        return [
            {"status": "completed", "rms_error": 1.0 / p[KP], "oscillating": float(p[KP] / p[GAMMA] > 0.02)}
            for p in points
        ]

    end = drive(proc, "t", ratio)
    assert end.result.reason == "oscillating" and end.runs == 4  # γ = 1000, 562, 316 calm; 178 oscillates
    assert end.result.chosen.params[GAMMA] == pytest.approx(10**2.5)
    # Guideline 3: k_d,i = 10·10^(i/4) trips for k_d > 40 (i = 3); k_d = 31.6 oscillates, 17.8 does not
    g3 = Guideline3(5.0, 40.0 * math.pi, 10.0, 1e4, 1e5, 4, None, None)

    def plant(points):
        return [
            {
                "status": "aborted" if p[KD] > 40.0 or p[KP] > 800.0 else "completed",
                "rms_error": 1.0 / (p[KP] * p[KD]),
                "oscillating": float(25.0 < p[KD] <= 40.0),
            }
            for p in points
        ]

    end = drive(g3, "t", plant)
    assert end.result.detail["k_d"] == pytest.approx(10**1.25)  # the largest calm k_d below the trip


def test_the_walk_figure_draws_an_aborted_run_at_the_top_line_and_marker_alike():
    """An aborted run's RMS up to its abort (1.5 here) is lower than its neighbours'; the walk's
    line dipped to it while its marker sat at the top, as the axis label says aborted runs are."""
    import pandas as pd
    from matplotlib.collections import PathCollection

    from labrunner.campaign.guided_report import walk_figure

    table = pd.DataFrame(
        {
            "step": [1, 2, 3, 4],
            "stage": ["walk", "walk", "walk", "walk"],
            "status": ["completed", "completed", "aborted", "completed"],
            "rms_error": [4.0, 3.0, 1.5, 2.0],
            "chosen": [False, False, False, True],
            "controller.gamma": [1e3, 1e2, 1e1, 50.0],
        }
    )
    top = walk_figure(table, "t").axes[0]
    (line,) = [ln for ln in top.get_lines() if len(ln.get_xdata()) == 4]
    assert list(line.get_ydata()) == [4.0, 3.0, 4.0, 2.0]
    aborted = next(c for c in top.collections if isinstance(c, PathCollection) and c.get_label() == "aborted")
    assert aborted.get_offsets().tolist() == [[3.0, 4.0]]
