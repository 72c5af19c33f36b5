"""The checks of ``labrunner reproduce`` on synthetic metrics tables: each verdict kind (agrees, disagrees,
not testable) is reached by a table built to reach it, and flips when the table is changed against the
claim — so no check is a verdict that cannot fail."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from labrunner.reproduce import checks, checks_papers, checks_plate
from labrunner.reproduce.items import ITEMS
from labrunner.reproduce.report import counts, verdict_kind
from labrunner.reproduce.run import CampaignResult
from labrunner.reproduce.verdict import Part, at_boundary, combine


def result(name: str, frame: pd.DataFrame, parameters=None) -> dict[str, CampaignResult]:
    return {
        f"campaigns/x/{name}.toml": CampaignResult(f"campaigns/x/{name}.toml", Path("."), frame, {}, parameters or [])
    }


def test_combine_gives_each_kind_and_any_disagreeing_part_decides():
    yes, no, na = Part("a", "m", True), Part("b", "m", False), Part("c", "m", None)
    assert combine([yes, yes]).agrees is True and combine([yes, yes]).kind == "agrees"
    assert combine([yes, no, na]).agrees is False and combine([yes, no]).kind == "disagrees"
    assert combine([na, na]).agrees is None and combine([na]).kind == "not testable"
    assert combine([na, yes]).agrees is True  # a part the twin cannot test neither helps nor hurts
    assert "DISAGREES" in combine([yes, no]).measured


def lines_frame(rms_by_line: list[list[float]], statuses=None) -> pd.DataFrame:
    """Three runs on each line of constant γ/k_p (ratios 2, 6.3, 20), products 10⁴, 10⁵, 10⁶."""
    rows = []
    for i, (ratio, rms) in enumerate(zip((2.0, 6.3, 20.0), rms_by_line)):
        for j, (product, value) in enumerate(zip((1e4, 1e5, 1e6), rms)):
            status = statuses[i][j] if statuses else "completed"
            rows.append(
                {
                    "controller.gamma": np.sqrt(product * ratio),
                    "controller.k_p": np.sqrt(product / ratio),
                    "rms_error": value,
                    "outcome": status,
                    "oscillating": 0.0,
                    "max_abs_input": 1.0,
                }
            )
    return pd.DataFrame(rows)


def test_constant_ratio_lines_agree_only_when_the_ratio_separates_the_lines():
    alike = lines_frame([[0.44, 0.45, 0.46], [1.22, 1.25, 1.26], [3.3, 3.4, 3.4]])
    assert checks.constant_ratio_lines(result("lines", alike)).agrees is True
    # one line spreads more than the gap to its neighbour: the individual gains matter
    spread = lines_frame([[0.44, 0.45, 1.1], [1.22, 1.25, 1.26], [3.3, 3.4, 3.4]])
    assert checks.constant_ratio_lines(result("lines", spread)).agrees is False
    # the RMS falls as the ratio rises: the claim's ordering fails
    reversed_ = lines_frame([[3.3, 3.4, 3.4], [1.22, 1.25, 1.26], [0.44, 0.45, 0.46]])
    assert checks.constant_ratio_lines(result("lines", reversed_)).agrees is False
    # one run of a line aborted: the line is not alike
    mixed = lines_frame(
        [[0.44, 0.45, 0.46], [1.22, 1.25, 1.26], [3.3, 3.4, 3.4]],
        [["completed", "aborted", "completed"], ["completed"] * 3, ["completed"] * 3],
    )
    assert checks.constant_ratio_lines(result("lines", mixed)).agrees is False


def test_mfc_vs_ffc_disagrees_at_one_end_value():
    ends = [4.0, 10.0, 14.0]
    params = [{"reference.levels": [2.0, e, 2.0]} for e in ends]

    def both(mfc, ffc):
        return {
            **result("fig09-10-mfc", pd.DataFrame({"rms_error@tracking": mfc}), params),
            **result("fig09-10-ffc", pd.DataFrame({"rms_error@tracking": ffc}), params),
        }

    assert checks_papers.mfc_vs_ffc(both([0.5, 0.6, 0.7], [2.2, 2.5, 3.0])).agrees is True
    assert checks_papers.mfc_vs_ffc(both([0.5, 2.6, 0.7], [2.2, 2.5, 3.0])).agrees is False


def test_plate_input_gains_each_sub_claim_can_fail():
    factors = (0.5, 0.6, 0.7, 0.84, 0.875, 1.0, 1.2, 1.5)
    nominal = {"v": 1.0, "force": 1.0, "u": 1.6e-5, "current": 0.04}

    def frame(v_best=0.6, v_half="aborted", f84="aborted", u14=5.0):
        rows = []
        for law, g0 in nominal.items():
            for f in factors:
                rms = 6.0 + abs(f - (v_best if law == "v" else 1.0))
                status = "completed"
                if law == "v" and f == 0.5:
                    status = v_half
                if law == "force" and f == 0.84:
                    status = f84
                if law == "u" and f == 0.875:
                    rms = u14
                rows.append(
                    {
                        "controller.input": law,
                        "controller.gamma": g0 * f,
                        "outcome": status,
                        "oscillating": 0.0,
                        **{f"rms_e_hat_y{j}@move": rms * 1e-6 for j in (1, 2, 3)},
                    }
                )
        return result("fig08", pd.DataFrame(rows))

    assert checks_plate.plate_input_gains(frame()).agrees is True
    assert checks_plate.plate_input_gains(frame(v_best=0.84)).agrees is False
    assert checks_plate.plate_input_gains(frame(v_half="completed")).agrees is False
    verdict = checks_plate.plate_input_gains(frame(f84="completed"))  # γ_F: the paper blames its force law
    assert verdict.agrees is True and "cannot carry the claim [not testable]" in verdict.measured
    assert checks_plate.plate_input_gains(frame(u14=7.0)).agrees is False


def test_table3_parts_not_run_are_not_testable_and_the_sensor_fault_decides():
    def experiment(name, mbc, laws):
        window = "fault"
        m = pd.DataFrame([{f"rms_e_hat_y{j}@{window}": mbc * 1e-6 for j in (1, 2, 3)}])
        f = pd.DataFrame(
            [
                {"controller.input": law, **{f"rms_e_hat_y{j}@{window}": v * 1e-6 for j in (1, 2, 3)}}
                for law, v in laws.items()
            ]
        )
        return {**result(f"table3-{name}-mbc", m), **result(f"table3-{name}-mfc", f)}

    laws = {"v": 56.4, "force": 45.8, "u": 17.0, "current": 46.1}
    only_sensor = experiment("sensor", 41.9, laws)
    verdict = checks_plate.table3(only_sensor)
    assert verdict.agrees is True and verdict.measured.count("[not testable]") == 2
    assert checks_plate.table3(experiment("sensor", 60.0, laws)).agrees is False  # the MBC loses: reversed
    # the movement: MFC v at half the MBC agrees; at 0.9 of it, "almost half" fails
    move = experiment("horizontal", 8.0, {"v": 4.0, "force": 5.0, "u": 5.0, "current": 30.0})
    assert checks_plate.table3({**only_sensor, **move}).agrees is True
    slow = experiment("horizontal", 8.0, {"v": 7.2, "force": 7.5, "u": 7.5, "current": 30.0})
    assert checks_plate.table3({**only_sensor, **slow}).agrees is False


def test_a_point_off_the_predicted_boundary_counts_against_the_bound():
    frame = pd.DataFrame({"controller.k_p": [1.0, 2.0, 4.0, 8.0, 16.0], "predicted_stable": [1.0, 1.0, 1.0, 0.0, 0.0]})
    assert list(at_boundary(frame, ["controller.k_p"])) == [False, False, True, True, False]


def test_items_state_place_claim_and_tolerance_and_the_not_reproduced_say_why():
    for item in ITEMS:
        assert item.place and item.claim, item.id
        if item.reproduced:
            assert item.tolerance, item.id
        else:
            assert item.reason.startswith(("not testable", "not reproduced", "covered by")), item.id
    ids = [i.id for i in ITEMS]
    assert len(ids) == len(set(ids))
    n = counts(ITEMS, {})
    assert n["not testable"] + n["not reproduced"] == sum(not i.reproduced for i in ITEMS)
    assert verdict_kind(next(i for i in ITEMS if i.id == "valve-6"), {}) == "not testable"


@pytest.mark.parametrize("item_id", ["ident"])
def test_a_calibrated_claim_is_never_an_agreement(item_id):
    item = next(i for i in ITEMS if i.id == item_id)
    assert item.calibration and "fitted" in item.calibration


def test_walk_steps_are_counted_as_the_thesis_counts_them():
    """Thesis Sec. 3.5.3's counting on a hand-made pair of walks: a step is a change of the setting from
    the start to the choice. Polack: feed-forward γ 10⁴ → 10³ → 100 → 50 (chosen, 3 steps), 20 trips
    (not a step); feedback at γ = 50: k_p 0 → 0.1 → 1 → 10 (chosen, 3 steps), 100 trips; 6 steps.
    Guideline 2 reaches Polack's RMS (0.5) at its third run: 2 steps."""
    from labrunner.campaign.guided import Advance, Observation, Result, WalkStep
    from labrunner.reproduce.checks_walks import facts

    def obs(i, gamma, kp, status, rms, oscillating=False):
        return Observation(f"p{i}", {"controller.gamma": gamma, "controller.k_p": kp}, status, rms, 1.0, oscillating)

    ff = [obs(0, 1e4, 0.0, "no-motion", 9.0), obs(1, 1e3, 0.0, "completed", 8.0), obs(2, 100.0, 0.0, "completed", 6.0)]
    ff += [obs(3, 50.0, 0.0, "completed", 5.0), obs(4, 20.0, 0.0, "aborted", None)]
    fb = [
        obs(5, 50.0, 0.1, "completed", 3.0),
        obs(6, 50.0, 1.0, "completed", 1.0),
        obs(7, 50.0, 10.0, "completed", 0.5),
    ]
    fb += [obs(8, 50.0, 100.0, "aborted", None)]
    walk = tuple(WalkStep("ff", o, True) for o in ff) + tuple(WalkStep("fb", o, True) for o in fb)
    polack = Advance((), "", Result(fb[2], "tripped"), walk)
    g2_obs = [obs(10, 1e4, 10.0, "completed", 0.9), obs(11, 1e3, 100.0, "completed", 0.6)]
    g2_obs += [obs(12, 100.0, 1000.0, "completed", 0.45)]
    g2 = Advance((), "", Result(g2_obs[-1], "tripped"), tuple(WalkStep("g2", o, True) for o in g2_obs))
    f = facts(polack, g2)
    assert f["steps"] == {"polack_ff": 3, "polack_fb": 3, "guideline2": 2}
    assert f["ff_choice"].params["controller.gamma"] == 50.0 and f["g2"].id == "p12"
    assert f["runs"] == {"polack": 9, "guideline2": 3}


def test_a_check_that_agrees_on_its_falsification_variant_is_not_discriminating():
    from labrunner.reproduce.verdict import Judged, Verdict

    yes, no, na = Verdict("m", True), Verdict("m", False), Verdict("m", None)
    undecided = Verdict("m", None, undecided=True)
    assert Judged(yes, no).kind == "agrees"
    assert Judged(yes, yes).kind == "not discriminating"  # agrees on a variant built to fail the claim
    assert Judged(yes, na).kind == "not discriminating"  # the variant cannot show the check can fail
    assert Judged(yes, None).kind == "not discriminating"  # no variant declared
    assert Judged(no, no).kind == "disagrees"
    assert Judged(no, yes).kind == "not discriminating"  # passes the wrong variant, fails the twin
    assert Judged(na, yes).kind == "not testable" and Judged(undecided, None).kind == "undecided"


def test_an_undecided_part_makes_the_verdict_undecided_unless_another_part_disagrees():
    yes, no = Part("a", "m", True), Part("b", "m", False)
    open_ = Part("c", "m", None, "runs too short")
    assert combine([yes, open_]).kind == "undecided" and "undecided: runs too short" in combine([open_]).measured
    assert combine([no, open_]).kind == "disagrees"


def test_the_variant_runs_the_same_check_with_its_references_and_its_files_in_place():
    """Paper 1 Figs. 9/10 against its variant (the MFC's runs in the FFC's place): the same check, and
    it must disagree there — MFC against itself is not lower."""
    from labrunner.reproduce.report import judged

    item = next(i for i in ITEMS if i.id == "valve-9-10")
    params = [{"reference.levels": [2.0, e, 2.0]} for e in (4.0, 10.0, 14.0)]
    mfc, ffc = item.files
    results = {
        mfc: CampaignResult(mfc, Path("."), pd.DataFrame({"rms_error@tracking": [0.5, 0.6, 0.7]}), {}, params),
        ffc: CampaignResult(ffc, Path("."), pd.DataFrame({"rms_error@tracking": [2.2, 2.5, 3.0]}), {}, params),
    }
    j = judged(item, results)
    assert j.twin.kind == "agrees" and j.variant.kind == "disagrees" and j.kind == "agrees"
    same = {**results, ffc: results[mfc]}  # a twin whose FFC is as good as its MFC
    assert judged(item, same).kind == "disagrees"


def test_a_verdict_hanging_on_the_detectors_undecided_runs_is_undecided():
    from labrunner.reproduce.report import decided
    from labrunner.reproduce.verdict import Verdict

    frame = pd.DataFrame({"outcome": ["completed"] * 3, "oscillating": [1.0, 0.0, 0.0], "undecided": [1.0, 0.0, 0.0]})

    def none_oscillates(results, ref=None):
        f = next(iter(results.values())).frame
        return Verdict(f"{int(f['oscillating'].sum())} flagged", not f["oscillating"].any())

    assert decided(none_oscillates, result("x", frame)).kind == "undecided"
    firm = frame.assign(undecided=0.0)  # the same flag from a rule that holds on short runs
    assert decided(none_oscillates, result("x", firm)).kind == "disagrees"


def test_every_reproduced_item_declares_a_variant_and_its_references_are_the_checks():
    import inspect

    from labrunner.reproduce.report import _check

    for item in ITEMS:
        if not item.reproduced or item.id == "ident":
            continue
        assert item.variant is not None and item.variant.what, item.id
        assert set(item.variant.files) <= set(item.files) and set(item.variant.files.values()) <= set(item.files)
        assert "ref" in inspect.signature(_check(item.check)).parameters, item.id


def test_valve_parametrisations_disagree_with_no1s_map_shifted():
    keys = {"controller.gamma": [0.01, 0.1, 1.0, 10.0], "controller.k_p": [1.0, 10.0, 100.0, 1000.0]}
    rows = []
    for n, (alpha, omega) in enumerate(((2, 250.0), (4, 850.0))):
        for g in keys["controller.gamma"]:
            for k in keys["controller.k_p"]:
                unstable = g * k > 50.0 + 40.0 * n  # No. 2's boundary a little off No. 1's
                rows.append(
                    {
                        "differentiator.alpha": alpha,
                        "differentiator.omega_c": omega,
                        "controller.gamma": g,
                        "controller.k_p": k,
                        "outcome": "aborted" if unstable else "completed",
                        "oscillating": 0.0,
                    }
                )
    frame = result("fig07", pd.DataFrame(rows))
    assert checks_papers.valve_parametrisations(frame).agrees is True
    assert checks_papers.valve_parametrisations(frame, ref={"shift": 2}).agrees is False


def test_the_backlash_is_fitted_on_the_feed_forward_edge_and_judged_on_table_3_1():
    from labrunner.reproduce.checks_calibration import edges

    ladder = 10 ** (np.arange(2.125, 1.49, -1 / 16))
    rows = [
        {"controller.gamma": g, "rig_parameters.backlash": b, "outcome": "completed" if g >= edge else "aborted"}
        for b, edge in ((0.02, 48.6), (0.25, 64.9))
        for g in ladder
    ]
    table = edges(pd.DataFrame(rows))
    assert list(table["edge γ_Ω"].round(1)) == [48.7, 64.9]
    assert abs(table["rungs from the thesis's"].iloc[1]) < 0.01 and table["rungs from the thesis's"].iloc[0] < -1.9


def test_the_valves_saturated_level_is_read_per_row_and_only_saturated_rows_count():
    """calib-valve's calibration table: each zip row names the one parameter off the shipped twin; a row
    whose runs do not all oscillate at i_max is not saturated (its RMS is not the valve's)."""
    from labrunner.reproduce.checks_calibration import saturated_levels

    shipped = {"main_tau": 0.015, "downstream_conductance": 6.0}
    rows = []
    for tau, gd, rms, current in ((0.015, 6.0, 12.9, 1.01), (0.015, 2.5, 7.9, 1.01), (0.1, 6.0, 5.4, 0.9)):
        for k_p, dr in ((1.0, 0.0), (10.0, 0.2)):
            rows.append(
                {
                    "rig_parameters.main_tau": tau,
                    "rig_parameters.downstream_conductance": gd,
                    "controller.k_p": k_p,
                    "outcome": "completed",
                    "oscillating": 1.0,
                    "rms_error": rms + dr,
                    "max_abs_input": current,
                }
            )
    table = saturated_levels(pd.DataFrame(rows), shipped, i_max=1.01)
    assert list(table["parameter"]) == ["shipped twin", "downstream_conductance", "main_tau"]
    assert list(table["value"].fillna(-1)) == [-1, 2.5, 0.1]
    assert list(table["saturated RMS(e_q) [l/min]"].round(2)) == [13.0, 8.0, 5.5]
    assert list(table["all saturated"]) == [True, True, False]  # main_tau 0.1: the current stays below i_max
    assert table["spread over k_p [l/min]"].round(2).tolist() == [0.2, 0.2, 0.2]


def test_figs_9_10_validation_needs_the_mfc_settled_at_every_end_value_and_the_fitted_runs_only():
    """calib-valve's validation: the MFC below the FFC at every end value and settled at each; runs_at cuts
    every validation file to the fitted conductance (and is None where a grid lacks it)."""
    from labrunner.reproduce.checks_calibration import SETTLED_TOL, runs_at, settled_and_lower

    ends = [4.0, 14.0]
    params = [{"reference.levels": [2.0, e, 2.0]} for e in ends for _ in (2.5, 6.0)]
    gd = [2.5, 6.0] * 2

    def frame(tracking, settled):
        return pd.DataFrame(
            {"rig_parameters.downstream_conductance": gd, "rms_error@tracking": tracking, "rms_error@settled": settled}
        )

    results = {
        **result("calib-valve-fig09-10-mfc", frame([0.5, 0.5, 2.1, 0.7], [0.07, 0.05, 0.69, 0.06]), params),
        **result("calib-valve-fig09-10-ffc", frame([3.0, 2.2, 3.4, 3.0], [2.0, 1.2, 2.8, 1.2]), params),
    }
    files = ("fig09-10-mfc", "fig09-10-ffc")
    fitted = runs_at(results, files, "rig_parameters.downstream_conductance", 2.5)
    assert all(len(r.frame) == 2 and len(r.parameters) == 2 for r in fitted.values())
    assert runs_at(results, files, "rig_parameters.downstream_conductance", 3.0) is None
    verdict = settled_and_lower(fitted)  # lower at both, but 0.69 l/min off at 14 l/min
    assert verdict.agrees is False and "not at 14 l/min" in verdict.measured and 0.69 > SETTLED_TOL
    shipped = settled_and_lower(runs_at(results, files, "rig_parameters.downstream_conductance", 6.0))
    assert shipped.agrees is True and "lower at 2 of 2" in shipped.measured
