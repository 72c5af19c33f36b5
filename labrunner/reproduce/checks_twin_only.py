"""Checks of ``labrunner reproduce`` for thesis Figs. 3.16 and 3.18, which run on the twin only: the
k_p–k_d sweeps of the angle MFC with the safety routine switched off (the thesis made three and two such
runs on the motor). Same contract as :mod:`labrunner.reproduce.checks`."""

from __future__ import annotations

from labrunner.reproduce.verdict import NO_REF, Part, Ref, Results, Verdict, bound_parts, combine, one

KP, KD = "controller.k_p", "controller.k_d"


def safety_off(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.16 (twin only): with the safety routine off, the runs it aborted inside the bounds are stable
    and the runs beyond the bound switch between ±12 V (input at its limits: the detector's pinned or
    saturated oscillation). "Beyond the bound": every point predicted unstable more than a grid step
    from the boundary, whatever the safety-on run did (selecting only the mismatched ones would leave
    out the very points the claim is about)."""
    on = next(r for f, r in results.items() if "safety-off" not in f)
    off = next(r for f, r in results.items() if "safety-off" in f)
    _, pred = bound_parts(on, "motor", "", bound=ref.get("bound"))
    keys = [KP, KD]
    cols = {
        "outcome": "outcome_off",
        "oscillating": "oscillating_off",
        "limit_hits_per_s": "hits_off",
        "pinned_share": "pinned_off",
    }
    merged = pred.merge(off.frame[[*keys, *cols]].rename(columns=cols), on=keys)
    flagged = (merged["outcome_off"] == "completed") & (merged["oscillating_off"] == 1.0)
    merged["off"] = merged["outcome_off"].where(~flagged, "oscillating")
    inside = merged[merged["predicted_stable"].astype(bool) & (merged["observed"] == "aborted") & merged["far"]]
    beyond = merged[~merged["predicted_stable"].astype(bool) & ~merged["at_boundary"]]
    at_limits = (beyond["hits_off"] >= 2.0) | (beyond["pinned_off"] >= 0.5)
    parts = [
        Part(
            "the runs aborted inside the bounds are stable without the safety routine",
            f"{int((inside['off'] == 'completed').sum())} of {len(inside)} stable",
            bool((inside["off"] == "completed").all()) if len(inside) else None,
        ),
        Part(
            "beyond the bound the input switches between ±12 V",
            f"{int(at_limits.sum())} of {len(beyond)} at the limits",
            bool(at_limits.all()) if len(beyond) else None,
        ),
    ]
    return combine(parts, merged[[*keys, "predicted_stable", "observed", "off"]].round(4))


def safety_off_low_kd(results: Results, ref: Ref = NO_REF) -> Verdict:
    """Fig. 3.18 (twin only, γ_θ = 1.1 b, k_d ≤ 10 1/s, safety routine off): the points (2.58)–(2.59) call
    unstable reach ±12 V (the detector's saturated oscillation or pinned input); one it calls stable
    oscillates around the reference for lack of damping (the detector flags it) instead of settling.
    Both selections are every point more than a grid step on that side of the bound, whatever it did."""
    run = one(results)
    _, frame = bound_parts(run, "motor", "", bound=ref.get("bound"))
    frame = frame.merge(run.frame[[KP, KD, "limit_hits_per_s", "pinned_share"]], on=[KP, KD], suffixes=("", "_x"))
    beyond = frame[~frame["predicted_stable"].astype(bool) & ~frame["at_boundary"]]
    inside = frame[frame["predicted_stable"].astype(bool) & ~frame["at_boundary"]]
    at_limits = (beyond["limit_hits_per_s"] >= 2.0) | (beyond["pinned_share"] >= 0.5)
    ringing = inside["observed"] != "completed"
    parts = [
        Part(
            "the points the bound calls unstable reach ±12 V",
            f"{int(at_limits.sum())} of {len(beyond)} at the limits",
            bool(at_limits.all()) if len(beyond) else None,
        ),
        Part(
            "a point the bound calls stable oscillates for lack of damping (Fig. 3.18's green square; the "
            "thesis ran one such point and does not print which)",
            f"{int(ringing.sum())} of {len(inside)} flagged oscillating",
            bool(ringing.any()) if len(inside) else None,
        ),
    ]
    return combine(parts, frame[[KP, KD, "predicted_stable", "observed", "limit_hits_per_s"]].round(4))
