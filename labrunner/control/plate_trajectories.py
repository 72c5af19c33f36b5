"""Reference trajectories of paper 2's plate experiments, built from the generic poly-5 set-points.

- :func:`lift`: Sec. 4.1 / 4.3.1 — from the rest position on the screws (≈ 5.5 mm) to 2 mm in 2 s,
  then 2 → 5 → 2 mm with 0.5 s transitions and 0.2 s holds (Fig. 11), the same for y_1, y_2, y_3.
- :func:`tilt`: Sec. 4.3.2 — from hovering horizontally at 2 mm, three individual transitions with
  different transition times (Fig. 12: y_2 done after 0.25 s, y_3 after 0.5 s) and back. The paper
  gives the times but not the levels; the default levels tilt the plate by ±0.5 mm at the sensors.
  A run starts on the screws, so the tilt begins with the same lift to the hover height.

Both return one :class:`~labrunner.control.trajectories.Setpoints` per sensor point, optionally
delayed by the differentiator's delay δ_t (Sec. 4.3.1).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.control.factory import Point, Section, reference
from labrunner.control.trajectories import Reference, Setpoints
from labrunner.errors import InvalidParameter, check_finite
from labrunner.rigs.base import RigInfo


def lift(
    *,
    rest: float = 5.5e-3,
    hover: float = 2e-3,
    high: float = 5e-3,
    lift_s: float = 2.0,
    settle_s: float = 0.5,
    transition_s: float = 0.5,
    hold_s: float = 0.2,
    delay_s: float = 0.0,
    field_prefix: str = "reference",
) -> tuple[Setpoints, Setpoints, Setpoints]:
    """Lift ``rest`` → ``hover`` in ``lift_s``, hold ``settle_s``, then hover → high → hover [m, s]."""
    one = Setpoints.build(
        [rest, hover, high, hover],
        [lift_s, transition_s, transition_s],
        [0.0, settle_s, hold_s, hold_s],
        delay_s,
        field_prefix=field_prefix,
    )
    return one, one, one


def tilt(
    *,
    rest: float = 5.5e-3,
    hover: float = 2e-3,
    targets: Sequence[float] = (2.5e-3, 1.5e-3, 2.5e-3),
    transitions_s: Sequence[float] = (0.75, 0.25, 0.5),
    lift_s: float = 2.0,
    settle_s: float = 0.5,
    hold_s: float = 0.5,
    delay_s: float = 0.0,
    field_prefix: str = "reference",
) -> tuple[Setpoints, Setpoints, Setpoints]:
    """Per sensor k: lift ``rest`` → ``hover`` in ``lift_s``, hover ``settle_s``, to ``targets[k]`` in
    ``transitions_s[k]``, hold, and back [m, s].

    Each point holds its target until the slowest transition is done plus ``hold_s``, so that the
    plate is tilted about both axes at once before it returns.
    """
    if len(targets) != 3 or len(transitions_s) != 3:
        raise InvalidParameter(
            f"{field_prefix}.targets",
            f"needs three targets and three transition times, got {len(targets)} and {len(transitions_s)}",
        )
    slowest = max(transitions_s)
    return tuple(  # type: ignore[return-value]
        Setpoints.build(
            [rest, hover, target, hover],
            [lift_s, t, t],
            [0.0, settle_s, slowest - t + hold_s, hold_s],
            delay_s,
            field_prefix=field_prefix,
        )
        for target, t in zip(targets, transitions_s)
    )


def reference_from_points(points: Sequence[Point], rig_info: RigInfo, *, delays_s: np.ndarray | None) -> Reference:
    """The batched reference (y_1, y_2, y_3) of plate controllers from the points' ``reference`` sections.

    ``kind = "lift"``: keys ``rest`` [m] (default: the rig's rest gap), ``hover``, ``high`` [m],
    ``lift``, ``settle``, ``transition``, ``hold`` [s] (see :func:`lift`); ``kind = "tilt"``: keys
    ``rest``, ``hover`` [m], ``targets`` [m, one per sensor], ``transitions`` [s, one per sensor],
    ``lift``, ``settle``, ``hold`` [s] (see :func:`tilt`). Both take ``delay`` (bool): delay by the differentiator's δ_t
    (``delays_s``, per run). Other kinds (setpoints, steps, sine) go to
    :func:`labrunner.control.factory.reference` with three outputs.
    """
    kind = Section(points, "reference").choice("kind", _KINDS, "setpoints")
    if kind not in ("lift", "tilt"):
        return reference(points, 3, delays_s=delays_s, kinds=("setpoints", "steps", "sine"))
    sec = Section(points, "reference", used=("kind",))
    delayed = sec.flag("delay", False)
    if delayed and delays_s is None:
        raise InvalidParameter("reference.delay", "this controller has no differentiator delay to delay by")
    delays = np.asarray(delays_s, dtype=float) if delayed else np.zeros(len(points))
    gap = dict(lo=0.0, lo_open=True, hi=float(rig_info.outputs[0].hi))
    rows = []
    rest = sec.number("rest", float(rig_info.constants.get("rest_gap", 5.5e-3)), **gap)
    hover = sec.number("hover", 2e-3, **gap)
    lift_s, settle = sec.number("lift", 2.0, lo=0.0, lo_open=True), sec.number("settle", 0.5, lo=0.0)
    if kind == "lift":
        high = sec.number("high", 5e-3, **gap)
        trans, hold = sec.number("transition", 0.5, lo=0.0, lo_open=True), sec.number("hold", 0.2, lo=0.0)
        for i in range(len(points)):
            rows.append(lift(rest=rest[i], hover=hover[i], high=high[i], lift_s=lift_s[i], settle_s=settle[i],
                             transition_s=trans[i], hold_s=hold[i], delay_s=delays[i]))  # fmt: skip
    else:
        targets = sec.values("targets", [2.5e-3, 1.5e-3, 2.5e-3])
        transitions = sec.values("transitions", [0.75, 0.25, 0.5])
        hold = sec.number("hold", 0.5, lo=0.0)
        for i in range(len(points)):
            tg = _triple("reference.targets", targets[i], **gap)
            tr = _triple("reference.transitions", transitions[i], lo=0.0, lo_open=True, hi=np.inf)
            rows.append(tilt(rest=rest[i], hover=hover[i], targets=tg, transitions_s=tr, lift_s=lift_s[i],
                             settle_s=settle[i], hold_s=hold[i], delay_s=delays[i]))  # fmt: skip
    sec.finish()
    return Reference(rows)


_KINDS = ("setpoints", "steps", "sine", "lift", "tilt")


def _triple(field: str, value: object, *, lo: float, lo_open: bool, hi: float) -> tuple[float, float, float]:
    """Three numbers in (lo, hi], one per sensor point."""
    if np.ndim(value) != 1 or len(value) != 3:  # type: ignore[arg-type]
        raise InvalidParameter(field, f"needs three numbers, one per sensor point, got {value!r}")
    out = tuple(check_finite(field, v) for v in value)  # type: ignore[union-attr]
    for v in out:
        if v < lo or (lo_open and v == lo) or v > hi:
            raise InvalidParameter(field, f"must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {v!r}")
    return out  # type: ignore[return-value]
