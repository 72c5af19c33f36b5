"""Which stability bounds belong on which map, and the lines that draw them.

A γ–k_p map of the first-order MFC (thesis Fig. 3.10) carries the ultra-local bound (2.41)
(pink) and the DC-motor bounds (2.46) (red: dashed the lower, solid the upper k_p), and a vertical
white line at the rig's nominal input gain ρ (= b for the motor). A k_p–k_d map of the
second-order MFC (Figs. 3.14–3.19) carries the corrected ultra-local bounds (2.53)/(2.54) (pink)
and the corrected motor bounds (2.58)/(2.59) (red): horizontal lines at the k_d limits and the
k_p limit as a curve over k_d. The bounds come from :func:`labrunner.stability.bounds`, with δ
the delay δ_t of the campaign's differentiator.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from labrunner.errors import InvalidParameter

#: Stability cases per controller kind: (ultra-local case, model case).
CASES = {"mfc1": ("mfc1-ultralocal", "mfc1-motor"), "mfc2": ("mfc2-ultralocal", "mfc2-motor")}
#: Thesis equations of each case, for labels.
EQUATIONS = {
    "mfc1-ultralocal": "(2.41)",
    "mfc1-motor": "(2.46)",
    "mfc2-ultralocal": "(2.53)–(2.54), corrected",
    "mfc2-motor": "(2.58)–(2.59), corrected",
}
_COLOURS = {"ultralocal": "#ff4fd8", "motor": "red"}


def _outline() -> tuple[object, ...]:
    """A thin dark outline: it keeps the white nominal-gain line visible on light cells and in
    the legend (matplotlib imported here, where a line is drawn: ``analyse`` computes the lines in
    a process that draws none)."""
    from matplotlib import patheffects

    return (patheffects.Stroke(linewidth=3.2, foreground="black"), patheffects.Normal())


@dataclass(frozen=True)
class OverlayLine:
    """One line on a map: a curve (x, y), or a vertical (``y`` None) / horizontal (``x`` None) line."""

    label: str
    x: np.ndarray | float | None
    y: np.ndarray | float | None
    color: str
    linestyle: str = "-"
    gid: str = ""
    outline: bool = False  # a thin dark outline (:func:`_outline`)

    def draw(self, ax) -> None:
        kw = {
            "color": self.color,
            "linestyle": self.linestyle,
            "label": self.label,
            "gid": self.gid,
            "linewidth": 1.8,
            "zorder": 3,
        }
        if self.outline:
            kw["path_effects"] = _outline()
        if self.y is None:
            ax.axvline(float(self.x), **kw)
        elif self.x is None:
            ax.axhline(float(self.y), **kw)
        else:
            ax.plot(self.x, self.y, **kw)


@dataclass(frozen=True)
class Theory:
    """Everything the bounds need: controller kind, rig constants (a, b, rho) and the loop's delay
    δ [s]: the differentiator's δ_t plus the rig's measurement dead time (the valve's flow sensor)."""

    kind: str
    delay: float
    constants: Mapping[str, float]
    dead_time: float = 0.0  # the part of ``delay`` that is the rig's sensor delay [s]

    def delay_note(self) -> str:
        """The delay as figures state it, e.g. ``δ_t = 35 ms`` or ``δ = δ_t + sensor delay = …``."""
        if not self.dead_time:
            return f"δ_t = {self.delay * 1e3:.4g} ms"
        estimation = self.delay - self.dead_time
        return f"δ = δ_t + sensor delay = {estimation * 1e3:.4g} + {self.dead_time * 1e3:.4g} ms"

    @property
    def rho(self) -> float | None:
        """Nominal input gain ρ of the ultra-local model (rig constant ``rho``, else ``b``)."""
        value = self.constants.get("rho", self.constants.get("b"))
        return None if value is None else float(value)

    @property
    def has_model(self) -> bool:
        return "a" in self.constants and "b" in self.constants

    def cases(self) -> list[str]:
        """The cases that apply: the ultra-local one if ρ is known, the motor one if a and b are."""
        if self.kind not in CASES:
            return []
        ultra, model = CASES[self.kind]
        return ([ultra] if self.rho is not None else []) + ([model] if self.has_model else [])

    def bounds(self, case: str, gamma: float, k_d: float | None = None) -> dict | None:
        """:func:`labrunner.stability.bounds` of ``case`` at this γ (and k_d); cached, since a grid
        repeats each (γ, k_d) along its other axis. None outside the theory's domain (γ ≤ 0, k_d <
        0, …): a grid that ``run`` accepts, or the half cell a map draws beyond its last value, may
        reach there, and the theory then says nothing."""
        gains = {"rho": self.rho} if case.endswith("ultralocal") else {k: float(self.constants[k]) for k in ("a", "b")}
        return _bounds(
            case, float(gamma), self.delay, tuple(sorted(gains.items())), None if k_d is None else float(k_d)
        )

    def k_p_limits(
        self, case: str, gammas: np.ndarray, k_ds: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the k_p interval of ``case`` at each γ (and k_d), NaN where none is stable:
        :meth:`bounds` once per distinct (γ, k_d) pair, not once per point of a dense axis."""
        g = np.asarray(gammas, dtype=float)
        kd = np.zeros_like(g) if k_ds is None else np.broadcast_to(np.asarray(k_ds, dtype=float), g.shape)
        pairs, inverse = np.unique(np.stack([g.ravel(), kd.ravel()], axis=1), axis=0, return_inverse=True)
        found = np.array(
            [_interval(self.bounds(case, gi, None if k_ds is None else kdi), "k_p") for gi, kdi in pairs]
        ).reshape(-1, 2)
        lo, hi = found[inverse.ravel()].T
        return lo.reshape(g.shape), hi.reshape(g.shape)

    def predict(self, case: str, params: Mapping[str, float]) -> tuple[bool, float] | None:
        """Whether ``case`` predicts a stable loop at ``params`` (gamma, k_p, k_d) and the relative
        distance to its nearest bound: min |g − bound| / bound over the gains g = k_p (and k_d)
        and their finite, positive bounds; None where the theory is not defined (see :meth:`bounds`).
        """
        k_d = params.get("k_d") if case.startswith("mfc2") else None
        b = self.bounds(case, float(params["gamma"]), None if k_d is None else float(k_d))
        if b is None:
            return None
        checks = [(float(params["k_p"]), _interval(b, "k_p"))]
        if k_d is not None:
            checks.append((float(k_d), _interval(b, "k_d")))
        stable = all(lo < g < hi for g, (lo, hi) in checks)
        distances = [abs(g - e) / e for g, pair in checks for e in pair if np.isfinite(e) and e > 0]
        return stable, min(distances, default=float("inf"))


@functools.lru_cache(maxsize=1 << 16)
def _bounds(
    case: str, gamma: float, delay: float, gains: tuple[tuple[str, float], ...], k_d: float | None
) -> dict | None:
    from labrunner import stability  # the solver is only needed where a map has a theory

    kw = dict(gains)
    if k_d is not None:
        kw["k_d"] = k_d
    try:
        return stability.bounds(case, gamma=gamma, delay=delay, **kw)
    except InvalidParameter:  # outside the case's domain: no bound there
        return None


def _interval(bounds: Mapping[str, object] | None, key: str) -> tuple[float, float]:
    value = None if bounds is None else bounds.get(key)
    return (np.nan, np.nan) if value is None else (float(value[0]), float(value[1]))


def _family(case: str) -> str:
    return case.split("-", 1)[1]


_MODELS = {"ultralocal": "ultra-local model", "motor": "motor model"}


def bound_label(case: str, which: str) -> str:
    """A bound's legend entry, saying what the line is and where it comes from:
    "stability bound, max k_p (motor model), Eq. (2.46)"."""
    eq = EQUATIONS[case]
    return f"stability bound, {which} ({_MODELS[_family(case)]}), {'Eqs.' if '–' in eq else 'Eq.'} {eq}"


def gamma_kp_lines(theory: Theory, gammas: np.ndarray) -> list[OverlayLine]:
    """Bounds of k_p over a dense γ axis (x = γ, y = k_p), and the nominal gain line."""
    lines = []
    for case in theory.cases():
        lo, hi = theory.k_p_limits(case, gammas)
        colour = _COLOURS[_family(case)]
        lines.append(OverlayLine(bound_label(case, "max k_p"), gammas, hi, colour, "-", f"bound:{case}:k_p_max"))
        if np.any(lo > 0):
            lines.append(
                OverlayLine(
                    bound_label(case, "min k_p"),
                    gammas,
                    np.where(lo > 0, lo, np.nan),
                    colour,
                    "--",
                    f"bound:{case}:k_p_min",
                )
            )
    if theory.rho is not None:
        lines.append(
            OverlayLine(
                f"nominal input gain ρ = {theory.rho:.5g}",
                theory.rho,
                None,
                "white",
                "-",
                "nominal-gain",
                outline=True,
            )
        )
    return lines


def kp_kd_lines(theory: Theory, gamma: float, k_ds: np.ndarray) -> list[OverlayLine]:
    """Bounds on a k_p–k_d map (x = k_p, y = k_d) at fixed γ: k_d limits and k_p(k_d) limits."""
    lines = []
    for case in theory.cases():
        colour = _COLOURS[_family(case)]
        first = theory.bounds(case, gamma, float(k_ds[0]))
        kd_lo, kd_hi = _interval(first, "k_d")
        lo, hi = theory.k_p_limits(case, np.full(len(k_ds), float(gamma)), k_ds)
        lines.append(OverlayLine(bound_label(case, "max k_p"), hi, k_ds, colour, "-", f"bound:{case}:k_p_max"))
        if np.any(lo > 0):
            lines.append(
                OverlayLine(
                    bound_label(case, "min k_p"),
                    np.where(lo > 0, lo, np.nan),
                    k_ds,
                    colour,
                    "--",
                    f"bound:{case}:k_p_min",
                )
            )
        if np.isfinite(kd_hi):
            lines.append(OverlayLine(bound_label(case, "max k_d"), None, kd_hi, colour, ":", f"bound:{case}:k_d_max"))
        if np.isfinite(kd_lo) and kd_lo > 0:
            lines.append(OverlayLine(bound_label(case, "min k_d"), None, kd_lo, colour, "-.", f"bound:{case}:k_d_min"))
    return lines


def transitions(values: np.ndarray, stable: Callable[[float], bool | None]) -> list[float]:
    """Points (geometric midpoints, arithmetic where a value is ≤ 0) where ``stable`` flips along
    sorted ``values``; values where it is None (no theory there) are skipped, not taken as a flip."""
    known = [(float(v), flag) for v in values if (flag := stable(float(v))) is not None]
    return [
        float(np.sqrt(a * b)) if a > 0 and b > 0 else (a + b) / 2
        for (a, fa), (b, fb) in zip(known, known[1:])
        if fa != fb
    ]


def sweep_lines(
    theory: Theory,
    key: str,
    dense: np.ndarray,
    fixed: Mapping[str, float],
    along: Callable[[float], Mapping[str, float]] | None = None,
) -> list[OverlayLine]:
    """Vertical lines at the predicted stability limits along a 1-D sweep of ``key`` (γ, k_p or k_d).
    The other gains are ``fixed``, except those ``along`` gives at a swept value (a derived gain
    that varies with the swept one: predicted where the runs were)."""

    def gains(v: float) -> dict[str, float]:
        return {**fixed, **(along(v) if along is not None else {}), key: v}

    lines = []
    for case in theory.cases():
        colour = _COLOURS[_family(case)]
        found = transitions(dense, lambda v: (p := theory.predict(case, gains(v))) and p[0])
        lines += [
            OverlayLine(
                bound_label(case, f"{'γ' if key == 'gamma' else key} limit") if i == 0 else "_",
                x,
                None,
                colour,
                "--",
                f"bound:{case}:{key}",
            )
            for i, x in enumerate(found)
        ]
    if key == "gamma" and theory.rho is not None:
        lines.append(
            OverlayLine(f"nominal input gain ρ = {theory.rho:.5g}", theory.rho, None, "grey", "-", "nominal-gain")
        )
    return lines


def dense_axis(values: Sequence[float], log: bool, num: int = 200) -> np.ndarray:
    """A dense axis spanning the grid values (log-spaced on a log axis)."""
    lo, hi = float(np.min(values)), float(np.max(values))
    return np.geomspace(lo, hi, num) if log else np.linspace(lo, hi, num)
