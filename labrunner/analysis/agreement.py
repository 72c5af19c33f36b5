"""How well the theory's stability prediction matches what the runs did.

A run that completed (or did not move: its loop was stable, its input just too small) counts as
observed stable, an aborted run as observed unstable; failed and unfinished runs are left out.
A completed run that the oscillation detector flags (input pinned at a limit, a saturated or a
growing oscillation: :mod:`labrunner.oscillation`) is observed unstable too: its observed outcome
reads "oscillating" (:func:`observed_outcome`; the table's ``outcome`` stays "completed").
The prediction is the model case of the campaign's controller (thesis (2.46) for the first-order
MFC, the corrected (2.58)–(2.59) for the second-order one; the ultra-local case where the rig has
no model). Points within ``margin`` (relative) of a predicted boundary are left out: there the
sampled grid cannot tell a boundary error from the discretisation of the experiment.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import pandas as pd

from labrunner.analysis.overlays import Theory

OBSERVED_STABLE = ("completed", "no-motion")
OBSERVED_UNSTABLE = ("aborted", "oscillating")
#: Table columns that hold the gains the stability cases need.
GAIN_COLUMNS = {"gamma": "controller.gamma", "k_p": "controller.k_p", "k_d": "controller.k_d"}


def observed_outcome(table: pd.DataFrame) -> pd.Series:
    """Each row's outcome, "oscillating" for a completed run the detector flagged (column ``oscillating``)."""
    outcome = table["outcome"]
    if "oscillating" not in table.columns:
        return outcome
    if isinstance(outcome.dtype, pd.CategoricalDtype) and "oscillating" not in outcome.cat.categories:
        outcome = outcome.cat.add_categories(["oscillating"])
    flagged = (outcome == "completed") & (pd.to_numeric(table["oscillating"], errors="coerce") == 1.0)
    return outcome.where(~flagged, "oscillating")


def table_gains(row: Mapping[str, object]) -> dict[str, float]:
    """γ, k_p, k_d of a table row from its grid columns (``controller.gamma``, ...)."""
    return {k: float(row[c]) for k, c in GAIN_COLUMNS.items() if c in row and pd.notna(row[c])}


def agreement(
    table: pd.DataFrame,
    theory_of: Callable[[Mapping[str, object]], Theory | None],
    *,
    gains_of: Callable[[Mapping[str, object]], Mapping[str, float]] = table_gains,
    margin: float = 0.1,
) -> dict[str, object]:
    """Share of compared points whose outcome matches the prediction, with the counts behind it.

    ``theory_of(row)`` gives the :class:`Theory` of a table row (a record of its parameter columns
    and outcome; its δ_t depends on the row's differentiator), or None when no stability case
    applies; ``gains_of(row)`` its γ, k_p, k_d (default: the grid columns; the analysis passes the
    resolved point, so fixed gains count too). Returns ``{"case", "share",
    "margin", "n_compared", "n_match", "n_excluded", "false_stable", "false_unstable",
    "observed_unstable", "oscillating"}`` (observed_unstable: compared runs that were aborted or
    oscillating);
    ``share`` is None when nothing could be compared; ``oscillating``: runs the detector turned
    from completed into observed unstable.
    """
    outcome = observed_outcome(table)
    compared_rows = outcome.isin(OBSERVED_STABLE + OBSERVED_UNSTABLE)
    params = table[[c for c in table.columns if "." in c]]  # what theory_of and gains_of read, not the metrics
    params = params.assign(outcome=outcome)[compared_rows]
    case = None
    match = excluded = false_stable = false_unstable = observed_unstable = 0
    for row in _records(params):
        theory = theory_of(row)
        if theory is None or not theory.cases():
            continue
        case = theory.cases()[-1]
        params = gains_of(row)
        if "gamma" not in params or "k_p" not in params or (case.startswith("mfc2") and "k_d" not in params):
            continue
        prediction = theory.predict(case, params)
        if prediction is None:  # outside the theory's domain: nothing to compare
            continue
        stable, distance = prediction
        if distance <= margin:
            excluded += 1
            continue
        ok = row["outcome"] in OBSERVED_STABLE
        observed_unstable += not ok
        match += ok == stable
        false_stable += stable and not ok
        false_unstable += ok and not stable
    compared = match + false_stable + false_unstable
    return {
        "case": case,
        "share": (match / compared) if compared else None,
        "margin": margin,
        "n_compared": int(compared),
        "n_match": int(match),
        "n_excluded": int(excluded),
        "false_stable": int(false_stable),
        "false_unstable": int(false_unstable),
        "observed_unstable": int(observed_unstable),
        "oscillating": int((outcome[compared_rows] == "oscillating").sum()),
    }


def _records(frame: pd.DataFrame, at_a_time: int = 10_000) -> Iterator[dict[str, object]]:
    """The rows of ``frame`` as dicts, made ``at_a_time`` at a time (10^6 dicts are ~0.4 GB)."""
    for start in range(0, len(frame), at_a_time):
        yield from frame.iloc[start : start + at_a_time].to_dict("records")
