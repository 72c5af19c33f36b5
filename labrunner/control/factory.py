"""Build a batch controller and its reference from resolved campaign points; validate points.

A *point* is a dict with the sections ``controller``, ``differentiator`` and ``reference`` (plus
sections other modules read, e.g. ``safety``). :func:`build` looks the controller kind up in
:data:`REGISTRY` (``kind → "module:function"``, imported only when chosen, so plate kinds live in
their own modules) and calls ``function(points, rig_info, fs) -> (Controller, Reference)``.
Builders read their sections through :class:`Section`, which gathers per-run values into arrays
with a leading batch axis, checks ranges, names the dotted key in every error and rejects unknown
keys. :func:`differentiators` designs one differentiator per run and re-keys the differentiator
module's own errors (α vs derivative order, ω_c vs Nyquist) to ``differentiator.<key>``.
A few choices a builder takes per run (:data:`PER_RUN_CHOICES`) need not agree over a batch.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from labrunner import differentiators as _diff
from labrunner.control.base import Controller
from labrunner.control.trajectories import Reference, Setpoints, Sine, Steps, Trajectory
from labrunner.errors import InvalidParameter, check_finite
from labrunner.rigs.base import RigInfo

Point = Mapping[str, object]
Builder = Callable[[Sequence[Point], RigInfo, float], tuple[Controller, Reference]]

#: Controller kinds → "module:function" builders (see :func:`register`).
REGISTRY: dict[str, str] = {
    "mfc1": "labrunner.control.mfc:build_mfc1",
    "mfc1-ff": "labrunner.control.mfc:build_mfc1_ff",
    "mfc2": "labrunner.control.mfc:build_mfc2",
    "open-loop": "labrunner.control.baselines:build_open_loop",
    "valve-ffc": "labrunner.control.baselines:build_valve_ffc",
    "plate-mfc": "labrunner.control.plate:build_plate_mfc",
    "plate-mbc": "labrunner.control.plate_mbc:build_plate_mbc",
}

#: (controller kind, ``controller`` key) of the choices its builder takes per run (``Section.choice``
#: with ``per_run=True``): runs that differ only in them may share a lockstep batch, each row computing
#: its own law (the plate MFC's four input laws: Table 3 would otherwise run four batches of one).
PER_RUN_CHOICES: frozenset[tuple[str, str]] = frozenset({("plate-mfc", "input")})


def per_run_paths(kind: object) -> frozenset[str]:
    """The dotted keys (``controller.<key>``) that controller ``kind`` takes per run."""
    return frozenset(f"controller.{key}" for k, key in PER_RUN_CHOICES if k == kind)


def register(kind: str, target: str) -> None:
    """Add or replace a controller kind: ``target`` is ``"package.module:function"``."""
    if ":" not in target:
        raise InvalidParameter("target", f"must be 'module:function', got {target!r}")
    REGISTRY[kind] = target


def builder(kind: object) -> Builder:
    """The builder of ``kind``, imported now."""
    if not isinstance(kind, str) or kind not in REGISTRY:
        raise InvalidParameter("controller.kind", f"must be one of {', '.join(sorted(REGISTRY))}, got {kind!r}")
    module, _, name = REGISTRY[kind].partition(":")
    return getattr(importlib.import_module(module), name)


def build(points: Sequence[Point], rig_info: RigInfo, fs: float) -> tuple[Controller, Reference]:
    """Controller and batched reference for B = len(points) runs sharing one controller kind."""
    if not points:
        raise InvalidParameter("points", "need at least one point")
    fs = rig_info.check_fs(check_finite("campaign.fs", fs), "campaign.fs")
    kinds = {str(dict(p.get("controller") or {}).get("kind")) for p in points}  # type: ignore[arg-type]
    if len(kinds) != 1:
        raise InvalidParameter("controller.kind", f"one batch needs one kind, got {sorted(kinds)}")
    kind = dict(points[0].get("controller") or {}).get("kind")  # type: ignore[arg-type]
    return builder(kind)(points, rig_info, fs)


def validate(point: Point, rig_info: RigInfo, fs: float) -> None:
    """Run every check :func:`build` runs for one point, without keeping what it builds."""
    build([point], rig_info, fs)


class Section:
    """One section (``controller``, ``reference``, …) of B points, read key by key.

    Every reader records its key; :meth:`finish` rejects keys nobody read. Numbers come back as
    (B,) float arrays; choices must agree over the batch unless read with ``per_run=True``.
    """

    def __init__(self, points: Sequence[Point], name: str, *, used: Sequence[str] = ()) -> None:
        self.name = name
        self.rows = [dict(p.get(name) or {}) for p in points]  # type: ignore[arg-type]
        self.used = set(used)

    def key(self, key: str) -> str:
        return f"{self.name}.{key}"

    def has(self, key: str) -> bool:
        self.used.add(key)
        return any(key in row for row in self.rows)

    def values(self, key: str, default: object = None) -> list[object]:
        """Raw per-run values (``default`` where absent; absent and no default → error)."""
        self.used.add(key)
        out = [row.get(key, default) for row in self.rows]
        if any(v is None for v in out):
            raise InvalidParameter(self.key(key), "is required")
        return out

    def number(
        self,
        key: str,
        default: float | np.ndarray | None = None,
        *,
        lo: float = -np.inf,
        hi: float = np.inf,
        lo_open: bool = False,
        integer: bool = False,
    ) -> np.ndarray:
        """(B,) floats in [lo, hi] (or (lo, hi] with ``lo_open``); ``default`` may be per run (B,)."""
        defaults = np.broadcast_to(np.asarray(default, dtype=object), (len(self.rows),))
        self.used.add(key)
        out = np.empty(len(self.rows))
        for i, (row, d) in enumerate(zip(self.rows, defaults)):
            if key not in row:  # defaults are trusted (e.g. a rig limit of ±inf)
                if d is None:
                    raise InvalidParameter(self.key(key), "is required")
                out[i] = float(d)
                continue
            v = row[key]
            if isinstance(v, bool):
                raise InvalidParameter(self.key(key), f"must be a number, got {v!r}")
            x = check_finite(self.key(key), v)  # type: ignore[arg-type]
            if integer and not x.is_integer():
                raise InvalidParameter(self.key(key), f"must be an integer, got {v!r}")
            if x < lo or (lo_open and x == lo) or x > hi:
                left = "(" if lo_open else "["
                raise InvalidParameter(self.key(key), f"must be in {left}{lo:g}, {hi:g}], got {v!r}")
            out[i] = x
        return out

    def choice(
        self, key: str, allowed: Sequence[str], default: str | None = None, *, per_run: bool = False
    ) -> list[str] | str:
        """A string from ``allowed``: the common value, or the list of per-run values."""
        vals = self.values(key, default)
        for v in vals:
            if v not in allowed:
                raise InvalidParameter(self.key(key), f"must be one of {', '.join(map(repr, allowed))}, got {v!r}")
        if per_run:
            return [str(v) for v in vals]
        if len(set(vals)) != 1:
            raise InvalidParameter(self.key(key), f"must be the same for every run of a batch, got {sorted(set(vals))}")
        return str(vals[0])

    def flag(self, key: str, default: bool) -> bool:
        """A boolean common to the batch."""
        vals = self.values(key, default)
        if any(not isinstance(v, (bool, np.bool_)) for v in vals):
            raise InvalidParameter(self.key(key), f"must be true or false, got {vals[0]!r}")
        if len(set(vals)) != 1:
            raise InvalidParameter(self.key(key), "must be the same for every run of a batch")
        return bool(vals[0])

    def finish(self) -> None:
        """Reject keys no reader asked for."""
        for row in self.rows:
            for k in row:
                if k not in self.used:
                    allowed = ", ".join(sorted(self.used)) or "none"
                    raise InvalidParameter(self.key(k), f"unknown key (allowed here: {allowed})")


def no_section(points: Sequence[Point], name: str, kind: str) -> None:
    """Reject a non-empty section that controller ``kind`` does not use."""
    for p in points:
        if p.get(name):
            raise InvalidParameter(name, f"controller kind {kind!r} uses no [{name}] section; remove it")


def _rekey(exc: InvalidParameter, section: str) -> InvalidParameter:
    """The same error with its field prefixed by ``section.`` (unless already a dotted path)."""
    field = exc.field if "." in exc.field else f"{section}.{exc.field}"
    return InvalidParameter(field, exc.message)


@functools.lru_cache(maxsize=4096)
def _design(
    alpha: float,
    beta: float,
    fs: float,
    omega_c: float | None,
    window: float | None,
    N: int,
    theta: float | None,
    method: str,
) -> _diff.Differentiator:
    return _diff.design(alpha=alpha, beta=beta, fs=fs, omega_c=omega_c, window=window, N=N, theta=theta, method=method)


def differentiators(points: Sequence[Point], fs: float, order: int) -> list[_diff.Differentiator]:
    """One differentiator per run from the ``differentiator`` section, usable up to derivative ``order``.

    Keys: ``alpha``, ``beta`` (default: alpha), ``N`` (default 0), ``theta`` (default: the
    differentiator's), exactly one of ``omega_c`` [rad/s] and ``window`` [s], ``method``
    (default "midpoint"). Errors of the differentiator module are re-keyed to this section.
    """
    sec = Section(points, "differentiator")
    alpha = sec.number("alpha")
    beta = sec.number("beta", alpha)
    N = sec.number("N", 0, lo=0, integer=True)
    theta = sec.values("theta", np.nan)
    has_wc, has_window = sec.has("omega_c"), sec.has("window")
    for row in sec.rows:
        if ("omega_c" in row) == ("window" in row):
            raise InvalidParameter("differentiator.omega_c", "give exactly one of omega_c [rad/s] and window [s]")
    omega_c = sec.number("omega_c", np.nan) if has_wc else np.full(len(sec.rows), np.nan)
    window = sec.number("window", np.nan) if has_window else np.full(len(sec.rows), np.nan)
    methods = sec.values("method", "midpoint")
    sec.finish()
    designs = []
    try:
        for i in range(len(sec.rows)):
            th = theta[i]
            th = None if isinstance(th, float) and np.isnan(th) else check_finite("theta", th)  # type: ignore[arg-type]
            d = _design(
                float(alpha[i]), float(beta[i]), float(fs),
                None if np.isnan(omega_c[i]) else float(omega_c[i]),
                None if np.isnan(window[i]) else float(window[i]),
                int(N[i]), th, str(methods[i]),
            )  # fmt: skip
            d.check_weights(order)  # raises for α, β too small for this derivative order
            designs.append(d)
    except InvalidParameter as exc:
        raise _rekey(exc, "differentiator") from None
    return designs


def _is_nested(value: object) -> bool:
    """A non-empty list of lists (ragged allowed)."""
    return isinstance(value, (list, tuple)) and bool(value) and all(isinstance(v, (list, tuple)) for v in value)


def _per_output(value: object, n_outputs: int, nested: bool) -> list[object]:
    """One entry per output: ``value`` split by output where it is a list of per-output lists
    (only when the levels are nested per output), else ``value`` for every output."""
    if nested and _is_nested(value):
        if len(value) != n_outputs:  # type: ignore[arg-type]
            raise InvalidParameter("reference.levels", f"needs one list per output ({n_outputs}), got {len(value)}")  # type: ignore[arg-type]
        return list(value)  # type: ignore[arg-type]
    return [value] * n_outputs


#: reference kinds → their keys (besides ``kind``)
REFERENCE_KEYS = {
    "setpoints": ("levels", "transition", "hold", "delay"),
    "steps": ("levels", "durations"),
    "sine": ("amplitude", "frequency", "duration", "offset"),
}


def reference(
    points: Sequence[Point],
    n_outputs: int = 1,
    *,
    delays_s: np.ndarray | None = None,
    kinds: Sequence[str] = ("setpoints",),
) -> Reference:
    """The batched reference from the ``reference`` section (the kind may differ per run).

    ``kind = "setpoints"``: ``levels``, ``transition`` [s], ``hold`` [s], ``delay`` (bool: delay by
    ``delays_s`` per run, paper 2 Sec. 4.3.1); ``"steps"``: ``levels``, ``durations`` [s];
    ``"sine"``: ``amplitude``, ``frequency`` [Hz], ``duration`` [s], ``offset``. With several
    outputs, ``levels`` (and the times) may be nested one list per output.
    """
    sec = Section(points, "reference")
    rows: list[list[Trajectory]] = []
    built: dict[str, list[Trajectory]] = {}  # runs with equal sections (and delays) share their trajectories
    for i, (kind, row) in enumerate(zip(sec.choice("kind", kinds, kinds[0], per_run=True), sec.rows)):
        key = repr((kind, row, None if delays_s is None else float(delays_s[i])))
        if key in built:
            rows.append(built[key])
            continue
        for k in row:
            if k != "kind" and k not in REFERENCE_KEYS[kind]:
                raise InvalidParameter(
                    sec.key(k), f"unknown key for kind {kind!r} (allowed: {', '.join(REFERENCE_KEYS[kind])})"
                )
        one = Section([{"reference": row}], "reference", used=("kind",) + REFERENCE_KEYS[kind])
        if kind == "setpoints":
            levels, transition, hold = one.values("levels")[0], one.values("transition")[0], one.values("hold")[0]
            delay = 0.0
            if one.flag("delay", False):
                if delays_s is None:
                    raise InvalidParameter("reference.delay", "this controller has no differentiator delay to delay by")
                delay = float(delays_s[i])
            nested = _is_nested(levels)
            per_out = zip(*(_per_output(v, n_outputs, nested) for v in (levels, transition, hold)))
            rows.append([Setpoints.build(lv, tr, ho, delay) for lv, tr, ho in per_out])  # type: ignore[arg-type]
        elif kind == "steps":
            levels, durations = one.values("levels")[0], one.values("durations")[0]
            nested = _is_nested(levels)
            per_out = zip(*(_per_output(v, n_outputs, nested) for v in (levels, durations)))
            rows.append([Steps.build(lv, du) for lv, du in per_out])  # type: ignore[arg-type]
        else:
            amp, freq, dur = one.number("amplitude")[0], one.number("frequency")[0], one.number("duration")[0]
            rows.append([Sine.build(amp, freq, dur, one.number("offset", 0.0)[0])] * n_outputs)
        built[key] = rows[-1]
    return Reference(rows)


def input_limits(sec: Section, rig_info: RigInfo, *, lo: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-run saturation limits (B, 1) of a single-input rig from ``u_min``/``u_max`` (default: the
    rig's input limits, which they must lie within); ``lo`` replaces ``u_min`` (e.g. the valve's i_min).
    """
    if len(rig_info.inputs) != 1:
        raise InvalidParameter(
            sec.key("kind"), f"needs a single-input rig, rig {rig_info.name!r} has {len(rig_info.inputs)}"
        )
    lo_rig, hi_rig = float(rig_info.input_lo[0]), float(rig_info.input_hi[0])
    u_min = sec.number("u_min", lo_rig, lo=lo_rig, hi=hi_rig) if lo is None else np.asarray(lo, dtype=float)
    u_max = sec.number("u_max", hi_rig, lo=lo_rig, hi=hi_rig)
    if np.any(u_min >= u_max):
        raise InvalidParameter(sec.key("u_max"), "must be > u_min (or i_min) for every run")
    return u_min[:, None], u_max[:, None]
