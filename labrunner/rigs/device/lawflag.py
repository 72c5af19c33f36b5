"""The reference-law check's flag as the ledger, ``status``, ``analyse`` and the report read it
(pure and import-light: ``labrunner status`` loads no numerics).

A device-loop run's outcome record carries ``diagnostics.law_check`` (:mod:`.lawcheck`): its
``flag`` is ``ok``, ``diverged@tick K`` or ``not-checked`` — a run that failed on a link fault too
(checked up to its last sample) — and its ``arithmetic``, the tolerance's: ``float64``, or
``float32`` for a device announcing FLOAT32 (a record without it is from before float32 devices:
float64). Runs without a device loop have none.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

OK, NOT_CHECKED, DIVERGED = "ok", "not-checked", "diverged"
FLOAT64, FLOAT32 = "float64", "float32"  #: a check's arithmetic (a record without one: float64)


def flag_of(outcome: Mapping[str, object] | None) -> str:
    """The law-check flag of an outcome record, "" for a run without one (a twin or host-loop
    run, or a record from before the check existed)."""
    diagnostics = (outcome or {}).get("diagnostics")
    record = diagnostics.get("law_check") if isinstance(diagnostics, Mapping) else None
    return str(record.get("flag", "")) if isinstance(record, Mapping) else ""


def arithmetic_of(outcome: Mapping[str, object] | None) -> str:
    """The arithmetic a run's law check was made under, "" for a run without a check."""
    diagnostics = (outcome or {}).get("diagnostics")
    record = diagnostics.get("law_check") if isinstance(diagnostics, Mapping) else None
    return str(record.get("arithmetic") or FLOAT64) if isinstance(record, Mapping) else ""


def diverged(flag: str) -> bool:
    return flag.startswith(DIVERGED)


def summary(flags: Iterable[tuple[str, str, str]]) -> dict[str, object] | None:
    """Counts of (point id, flag, arithmetic) triples per kind (ok, diverged, not-checked) and per
    arithmetic (``arithmetic``: float64 / float32 → runs), and the first diverged point; None when
    no run carries a flag."""
    counts: dict[str, int] = {OK: 0, DIVERGED: 0, NOT_CHECKED: 0}
    under: dict[str, int] = {}
    first = None
    for point, flag, arithmetic in flags:
        if not flag:
            continue
        kind = DIVERGED if diverged(flag) else flag
        counts[kind] = counts.get(kind, 0) + 1
        under[arithmetic or FLOAT64] = under.get(arithmetic or FLOAT64, 0) + 1
        if kind == DIVERGED and first is None:
            first = {"id": point, "flag": flag}
    if not any(counts.values()):
        return None
    return {**counts, "arithmetic": dict(sorted(under.items())), "first_diverged": first}


def line(summary: Mapping[str, object]) -> str:
    """One line for ``status`` and ``analyse``: the counts and the first diverged point."""
    text = (
        f"law check (device loop): {summary[OK]} ok, {summary[DIVERGED]} diverged, {summary[NOT_CHECKED]} not checked"
    )
    under = summary.get("arithmetic")
    if isinstance(under, Mapping) and under:
        text += " (checked under " + ", ".join(f"{a}: {n}" for a, n in under.items()) + ")"
    first = summary.get("first_diverged")
    if isinstance(first, Mapping):
        text += f"; first diverged: point {first['id']} ({first['flag']}) — the device did not run the law"
    return text
