"""Reference trajectories of paper 2's plate experiments, built from the generic poly-5 set-points.

- :func:`lift`: Sec. 4.1 / 4.3.1 — from the rest position on the screws (≈ 5.5 mm) to 2 mm in 2 s,
  then 2 → 5 → 2 mm with 0.5 s transitions and 0.2 s holds (Fig. 11), the same for y_1, y_2, y_3.
- :func:`tilt`: Sec. 4.3.2 — from hovering horizontally at 2 mm, three individual transitions with
  different transition times (Fig. 12: y_2 done after 0.25 s, y_3 after 0.5 s) and back. The paper
  gives the times but not the levels; the default levels tilt the plate by ±0.5 mm at the sensors.

Both return one :class:`~labrunner.control.trajectories.Setpoints` per sensor point, optionally
delayed by the differentiator's delay δ_t (Sec. 4.3.1).
"""

from __future__ import annotations

from collections.abc import Sequence

from labrunner.control.trajectories import Setpoints
from labrunner.errors import InvalidParameter


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
    hover: float = 2e-3,
    targets: Sequence[float] = (2.5e-3, 1.5e-3, 2.5e-3),
    transitions_s: Sequence[float] = (0.75, 0.25, 0.5),
    start_s: float = 0.2,
    hold_s: float = 0.5,
    delay_s: float = 0.0,
    field_prefix: str = "reference",
) -> tuple[Setpoints, Setpoints, Setpoints]:
    """Per sensor k: hover for ``start_s``, to ``targets[k]`` in ``transitions_s[k]``, hold, and back [m, s].

    Each point holds its target until the slowest transition is done plus ``hold_s``, so that the
    plate is tilted about both axes at once before it returns.
    """
    if len(targets) != 3 or len(transitions_s) != 3:
        raise InvalidParameter(f"{field_prefix}.targets", f"needs three targets and three transition times, got {len(targets)} and {len(transitions_s)}")
    slowest = max(transitions_s)
    return tuple(  # type: ignore[return-value]
        Setpoints.build(
            [hover, target, hover],
            [t, t],
            [start_s, slowest - t + hold_s, hold_s],
            delay_s,
            field_prefix=field_prefix,
        )
        for target, t in zip(targets, transitions_s)
    )
