"""The measured checks of ``labrunner reproduce``: each compares a finished campaign with its source's claim.

A check takes the item's results (``{file: CampaignResult}``) and returns a :class:`Verdict`: what
was measured (one sentence), whether it agrees with the claim (None: no yes/no answer), and a table
to print beside the source's numbers. Pure functions of the metrics tables; "observed unstable" is
aborted or oscillating (:func:`labrunner.analysis.agreement.observed_outcome`), as in the maps.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from labrunner.analysis.agreement import observed_outcome
from labrunner.reproduce.run import CampaignResult

Results = Mapping[str, CampaignResult]


@dataclass(frozen=True)
class Verdict:
    measured: str
    agrees: bool | None  # a plain bool (numpy's comparisons are converted)
    table: pd.DataFrame | None = None

    def __post_init__(self) -> None:
        if self.agrees is not None:
            object.__setattr__(self, "agrees", bool(self.agrees))


def single_result(results: Results, part: str = "") -> CampaignResult:
    return next(r for f, r in results.items() if part in f)


def _unstable(frame: pd.DataFrame) -> pd.Series:
    return observed_outcome(frame).isin(("aborted", "oscillating"))


def _done(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[observed_outcome(frame) == "completed"]


def identification(results: Results) -> Verdict:
    """Thesis Sec. 3.2's procedure on the twin's logs, plus the pooled fit with a Coulomb term."""
    from labrunner.identification import identify_logs, physical_parameters

    run = single_result(results)
    logs = sorted((run.directory / "runs").glob("*.mcap"))
    res = identify_logs(logs, friction=True)
    phys = physical_parameters(logs[0])
    da, db = res["a"] / 39.44 - 1, res["b"] / 108.55 - 1
    fric = res["friction"]
    table = pd.DataFrame(
        {
            "thesis": [39.44, 108.55, math.nan],
            "twin (thesis procedure)": [res["a"], res["b"], math.nan],
            "twin, with Coulomb term": [fric["a"], fric["b"], fric["coulomb"]],
            "twin's physical values": [phys["a"], phys["b"], phys["coulomb"]] if phys else [math.nan] * 3,
        },
        index=["a [1/s]", "b [rad/(V s²)]", "u_c [V]"],
    )
    return Verdict(
        f"a = {res['a']:.2f} ({da:+.1%}), b = {res['b']:.2f} ({db:+.1%}); the friction fit gives "
        f"u_c = {fric['coulomb']:.3f} V",
        abs(da) <= 0.03 and abs(db) <= 0.03,
        table,
    )


#: Table 3.2 of the thesis: unstable (α = β) at f_s = 200 Hz (a) and 1 kHz (b); none at 20 Hz (Fig. 3.7).
THESIS_UNSTABLE = {20.0: [], 200.0: [2, 2, 2, 3], 1000.0: [2, 2, 2, 3, 3]}


def unstable_differentiators(results: Results) -> Verdict:
    run = single_result(results)
    frame = run.frame
    bad = frame[_unstable(frame)]
    fs = _fs(run)
    pairs = sorted(zip(bad["differentiator.alpha"].astype(int), bad["differentiator.omega_c"]))
    expected = THESIS_UNSTABLE.get(fs, [])
    table = pd.DataFrame({"α = β": [p[0] for p in pairs], "ω_c [rad/s]": [p[1] for p in pairs]})
    measured = f"{len(pairs)} of {len(frame)} unstable" + (
        ": " + ", ".join(f"α = {a} at {w:g} rad/s" for a, w in pairs) if pairs else ""
    )
    return Verdict(measured, sorted(p[0] for p in pairs) == expected, table)


def _fs(run: CampaignResult) -> float:
    from labrunner.campaign import runner, spec

    return float(spec.load(run.directory / runner.CAMPAIGN_COPY).fs)


def _spread(values: np.ndarray) -> float:
    return float(values.max() / values.min() - 1.0) if len(values) > 1 else math.nan


def gamma_kp_map(results: Results) -> Verdict:
    """Bound agreement and the RMS spread along the grid's diagonals (constant γ/k_p on log axes)."""
    run = single_result(results)
    done = _done(run.frame).copy()
    done["line"] = np.round(np.log10(done["controller.gamma"] / done["controller.k_p"]), 6)
    rows = [
        {
            "log10 γ/k_p": line,
            "runs": len(g),
            "best RMS": g["rms_error"].min(),
            "spread": _spread(g["rms_error"].to_numpy()),
        }
        for line, g in done.groupby("line")
        if len(g) >= 3
    ]
    lines = pd.DataFrame(rows).sort_values("best RMS") if rows else pd.DataFrame()
    agree = run.summary["agreement"]
    edge = lines.iloc[0] if len(lines) else None
    text = (
        f"bound (2.46) agrees on {agree['share']:.1%} of {agree['n_compared']} points"
        if agree["share"] is not None
        else "no bound comparison"
    )
    if edge is not None:
        text += (
            f"; the best constant-ratio line (log10 γ/k_p = {edge['log10 γ/k_p']:g}, {int(edge['runs'])} runs) "
            f"spreads {edge['spread']:.1%} in RMS(e), the median line {lines['spread'].median():.1%}"
        )
    ok = agree["share"] is not None and agree["share"] >= 0.85 and edge is not None and edge["spread"] <= 0.05
    return Verdict(text, ok, lines)


def constant_ratio_lines(results: Results) -> Verdict:
    run = single_result(results)
    frame = run.frame.copy()
    frame["γ/k_p"] = frame["controller.gamma"] / frame["controller.k_p"]
    frame["status"] = observed_outcome(frame)
    lines = (
        frame.groupby(np.round(np.log10(frame["γ/k_p"]), 3))
        .agg(
            runs=("rms_error", "size"),
            stable=("status", lambda s: int((s == "completed").sum())),
            mean_rms=("rms_error", "mean"),
            spread=("rms_error", lambda v: _spread(v.to_numpy())),
        )
        .reset_index()
        .rename(columns={"γ/k_p": "log10 γ/k_p"})
    )
    stable = lines[lines["stable"] == lines["runs"]]
    ordered = bool(stable["mean_rms"].is_monotonic_increasing) if len(stable) > 1 else False
    worst = float(stable["spread"].max()) if len(stable) else math.nan
    text = (
        f"{len(stable)} of {len(lines)} lines stable throughout; RMS spread per line at most {worst:.1%}; "
        f"RMS {'rises' if ordered else 'does not rise'} with the ratio"
    )
    return Verdict(text, len(stable) == len(lines) and worst <= 0.10 and ordered, lines)


def bound_agreement(results: Results) -> Verdict:
    agree = single_result(results).summary["agreement"]
    if agree["share"] is None:
        return Verdict("no bound applies", None)
    table = pd.DataFrame(
        [
            {
                k: agree[k]
                for k in (
                    "case",
                    "n_compared",
                    "n_match",
                    "false_stable",
                    "false_unstable",
                    "n_excluded",
                    "oscillating",
                )
            }
        ]
    )
    return Verdict(
        f"{agree['case']} agrees on {agree['share']:.1%} of {agree['n_compared']} points "
        f"({agree['false_stable']} unstable where predicted stable, {agree['false_unstable']} stable "
        "where predicted unstable)",
        agree["share"] >= 0.85,
        table,
    )


def bound_conservative(results: Results) -> Verdict:
    """The claim that the bound predicts instability where runs are stable (below k_d,min, Fig. 3.19)."""
    verdict = bound_agreement(results)
    agree = single_result(results).summary["agreement"]
    if agree["share"] is None:
        return verdict
    n = agree["n_compared"]
    ok = agree["false_unstable"] > 0 and agree["false_stable"] <= 0.1 * n
    return Verdict(
        f"{verdict.measured}: the bound is {'conservative' if ok else 'not conservative'} here", ok, verdict.table
    )


def fine_kp_kd(results: Results) -> Verdict:
    verdict = bound_agreement(results)
    done = _done(single_result(results).frame)
    if done.empty:
        return verdict
    best = done.loc[done["rms_error"].idxmin()]
    lk, ld = math.log10(best["controller.k_p"]), math.log10(best["controller.k_d"])
    near = abs(lk - 3.1875) <= 0.25 and abs(ld - 1.9375) <= 0.25
    return Verdict(
        f"{verdict.measured}; best RMS(e_θ) = {best['rms_error']:.3g} rad at log10 k_p = {lk:.4g}, "
        f"log10 k_d = {ld:.4g}",
        bool(verdict.agrees and near),
        verdict.table,
    )
