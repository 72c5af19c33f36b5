"""Static per-point checks of a campaign, run on the whole grid before anything is created.

Every point goes through the validation its run would do, without moving a rig: the rig's f_s
range, :func:`labrunner.control.factory.build` (α vs the derivative order, ω_c vs the Nyquist
frequency π f_s, finite gains, rig limits, unknown keys), the safety monitors' configuration and
the run length. Points are checked in chunks of compatible points with one batched build each
(the builders are vectorised), so a 10 000-point grid takes seconds; a chunk that fails is
re-checked point by point so that the error names the offending grid point.

Compatibility ("may share a batch") is the campaign's rig, f_s, duration and every non-numeric
value of the point (controller kind, output, differentiator method, reference kind, ...):
builders require those to agree over a batch. A few numbers must agree too (e.g. the plate MFC's
notch frequency); they are discovered here: when a chunk fails to build although each of its
points builds alone, the key the error names joins :attr:`StaticChecker.split` and the chunk is
split by its value.

A controller's per-run choices (:data:`labrunner.control.factory.PER_RUN_CHOICES`, the plate MFC's
input law) are the exception: they do not split a chunk, and a point's batch key keeps them apart,
as a sixth element, so that the scheduler can merge keys that differ only there
(:func:`labrunner.campaign.scheduler.make_batches`). A point without any has the five-element key
of old ledgers.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from labrunner.campaign.grid import canonical_json
from labrunner.control import factory
from labrunner.errors import InvalidParameter, check_number, check_positive
from labrunner.rigs.base import RigConfig
from labrunner.rigs.config import rig_info
from labrunner.rigs.kinds import rig_class
from labrunner.safety import SafetyMonitor
from labrunner.safety_config import SafetyConfig

MAX_SAMPLES = 10_000_000  # samples per run: beyond this a run's signals do not fit a worker's memory
MAX_SEED = 2**63 - 1  # the simulated rigs' noise generators take int64 seeds
MAX_FIR_WORK = 2_000_000_000  # window taps × samples per run: beyond this one run's FIR alone takes minutes
CHUNK = 256  # points validated by one batched build

Item = tuple[int, dict[str, Any], dict[str, Any]]  # (seq, parameters, resolved config)


def lookup(config: dict[str, Any], key: str) -> Any:
    """The value at dotted ``key`` of a resolved point (None when absent)."""
    node: Any = config
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def batch_key(rig: str, config: dict[str, Any], split: list[str], known: list[tuple[str, Any]] | None = None) -> str:
    """Points with equal keys may share a lockstep batch (``config`` with its duration set;
    ``known``: its :func:`choices` if already found, e.g. :meth:`StaticChecker.choices`)."""
    head = config["campaign"]
    found = choices(config) if known is None else known
    return batch_key_of(rig, head["fs"], head["duration"], found, [lookup(config, k) for k in split])


def batch_key_of(rig: str, fs: float, duration: float, found: list[tuple[str, Any]], split_values: list[Any]) -> str:
    """:func:`batch_key` from its parts (the planner finds them without resolving each point twice):
    ``[rig, fs, duration, shared choices, split values]``, and the per-run choices where there are any."""
    shared, own = split_choices(found)
    return canonical_json([rig, fs, duration, shared, split_values, *([own] if own else [])])


def split_choices(found: list[tuple[str, Any]]) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """``found`` (:func:`choices`) as (the choices a batch shares, those its controller takes per run)."""
    per_run = factory.per_run_paths(dict(found).get("controller.kind"))
    if not per_run:
        return found, []
    return [c for c in found if c[0] not in per_run], [c for c in found if c[0] in per_run]


def lookup_point(params: dict[str, Any], base: dict[str, Any], key: str) -> Any:
    """:func:`lookup` of the point ``params`` sets over the configuration ``base`` (every point's
    keys but its parameters), without resolving it: a parameter is a leaf, so one that names a
    parent of ``key`` leaves nothing there."""
    if key in params:
        return params[key]
    if any(key.startswith(f"{k}.") for k in params):
        return None
    return lookup(base, key)


def shape(params: dict[str, Any]) -> tuple:
    """What of a point's parameters :func:`choices` can depend on: every key, with its value
    unless a number (the base configuration is the campaign's, the same for every point)."""
    return tuple(
        (k, "#number" if isinstance(v, int | float) and not isinstance(v, bool) else repr(v))
        for k, v in sorted(params.items())
    )


def choices(config: dict[str, Any]) -> list[tuple[str, Any]]:
    """The non-numeric leaves of a point's run sections: builders need them equal in a batch."""
    out: list[tuple[str, Any]] = []

    def walk(node: Any, path: str) -> None:
        if isinstance(node, dict):
            for k in sorted(node):
                walk(node[k], f"{path}.{k}" if path else k)
        elif isinstance(node, (str, bool)) or node is None:
            out.append((path, node))
        elif isinstance(node, list):
            out.append((f"{path}#len", len(node)))

    walk({k: v for k, v in config.items() if k != "campaign"}, "")
    return out


class StaticChecker:
    """Feed points with :meth:`add`; checked points come back with their run duration [s].

    ``rig`` is the campaign's validated rig file: its info (f_s range, signals, limits), its
    ``[safety]`` section and the rig kind's schema of per-run parameters.
    """

    def __init__(self, rig: RigConfig) -> None:
        self.rig = rig
        self.rig_info = rig_info(rig)
        self._pending: dict[str, list[Item]] = {}
        self._safety: set[str] = set()
        self._fs: set[float] = set()
        self.split: list[str] = []  # numeric keys that must agree within a batch (discovered)
        self._choices: dict[tuple, list[tuple[str, Any]]] = {}  # shape(params) → choices (self.choices)

    def choices(
        self, params: dict[str, Any], config: dict[str, Any] | Callable[[], dict[str, Any]]
    ) -> list[tuple[str, Any]]:
        """:func:`choices` of a point of this campaign (``config``: resolved from ``params``, or
        what resolves it), found once per :func:`shape` of the parameters: a grid of numbers has
        one (walking every point's tree, twice, was about a third of planning's CPU)."""
        key = shape(params)
        found = self._choices.get(key)
        if found is None:
            found = self._choices[key] = choices(config() if callable(config) else config)
        return found

    def add(self, seq: int, params: dict[str, Any], config: dict[str, Any]) -> Iterator[tuple[Item, float]]:
        """Queue one point; yields the checked points of a chunk once it is full."""
        self._scalars(params, config)
        shared, _ = split_choices(self.choices(params, config))  # per-run choices share a chunk, as a batch
        key = canonical_json([config["campaign"]["fs"], shared, [lookup(config, k) for k in self.split]])
        chunk = self._pending.setdefault(key, [])
        chunk.append((seq, params, config))
        if len(chunk) >= CHUNK:
            del self._pending[key]
            yield from self._check_chunk(chunk)

    def flush(self) -> Iterator[tuple[Item, float]]:
        """Check every queued point."""
        pending, self._pending = self._pending, {}
        for chunk in pending.values():
            yield from self._check_chunk(chunk)

    def _scalars(self, params: dict[str, Any], config: dict[str, Any]) -> None:
        head = config["campaign"]
        with _at(params):
            fs = check_positive("campaign.fs", head["fs"], strict=True)
            if fs not in self._fs:
                self.rig_info.check_fs(fs, "campaign.fs")
                self._fs.add(fs)
            seed = head["seed"]
            if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
                raise InvalidParameter("campaign.seed", f"must be an integer in [0, 2**63 - 1], got {seed!r}")
            if head["duration"] is not None:
                check_positive("campaign.duration", head["duration"], strict=True)
            for key, value in config.get("rig_parameters", {}).items():
                check_number(f"rig_parameters.{key}", value)
            self._check_safety(config.get("safety", {}), fs)

    def _check_rig_parameters(self, chunk: list[Item]) -> None:
        """Every point's ``[rig_parameters]`` through the rig kind's own schema and rules, batched
        as the engine passes them (NaN: the point keeps the rig file's value)."""
        sections = [c.get("rig_parameters", {}) for _, _, c in chunk]
        keys = sorted({k for s in sections for k in s})
        if not keys:
            return
        overrides = {k: np.array([float(s.get(k, np.nan)) for s in sections]) for k in keys}
        kind = rig_class(self.rig.kind)
        try:
            kind.check_overrides(self.rig, overrides, len(chunk), "rig_parameters")
        except InvalidParameter:
            for (_, params, _), section in zip(chunk, sections):  # name the first bad point
                with _at(params):
                    kind.check_overrides(self.rig, section, 1, "rig_parameters")
            raise

    def _check_chunk(self, chunk: list[Item]) -> Iterator[tuple[Item, float]]:
        self._check_rig_parameters(chunk)
        fs = float(chunk[0][2]["campaign"]["fs"])
        try:
            _, reference = factory.build([c for _, _, c in chunk], self.rig_info, fs)
        except InvalidParameter as exc:
            for item in chunk:  # find the first bad point, to name it
                with _at(item[1]):
                    factory.build([item[2]], self.rig_info, fs)
            # every point is fine alone: the points differ in a value a batch must share
            values = {canonical_json(lookup(c, exc.field)) for _, _, c in chunk}
            if exc.field in self.split or len(values) < 2:
                raise
            self.split.append(exc.field)
            groups: dict[str, list[Item]] = {}
            for item in chunk:
                groups.setdefault(canonical_json(lookup(item[2], exc.field)), []).append(item)
            for group in groups.values():
                yield from self._check_chunk(group)
            return
        taps = _window_taps(chunk, fs)
        for item, row, n_s in zip(chunk, reference.trajectories, taps):
            duration = item[2]["campaign"]["duration"]
            if duration is None:  # default: the reference's own length
                duration = max(tr.duration for tr in row)
            samples = round(float(duration) * fs)
            with _at(item[1]):
                if not 1 <= samples <= MAX_SAMPLES:
                    raise InvalidParameter(
                        "campaign.duration",
                        f"gives {samples:.6g} samples at {fs:g} Hz; allowed 1..{MAX_SAMPLES} (at most "
                        f"{MAX_SAMPLES / fs:g} s)",
                    )
                for name, t0 in _window_starts(item[2].get("metrics")):
                    if t0 >= samples / fs:
                        raise InvalidParameter(
                            f"metrics.{name}",
                            f"starts at {t0:g} s, at or after the run's end ({samples / fs:g} s): "
                            "its metrics would all be NaN",
                        )
                if n_s > samples:
                    raise InvalidParameter(
                        "differentiator.omega_c",
                        f"gives a window of {n_s} samples, longer than the run "
                        f"({samples} samples at {fs:g} Hz): no estimate would ever see a full window",
                    )
                if n_s * samples > MAX_FIR_WORK:
                    raise InvalidParameter(
                        "differentiator.omega_c",
                        f"gives a window of {n_s} samples; × {samples} samples per run "
                        f"that is more than the limit of {MAX_FIR_WORK:.0e} filter steps (raise omega_c or shorten the run)",
                    )
            yield item, float(duration)

    def _check_safety(self, section: dict[str, Any], fs: float) -> None:
        key = canonical_json([section, fs])
        if key not in self._safety:
            config = SafetyConfig.from_sections(self.rig_info, self.rig.safety, section)
            SafetyMonitor([config], self.rig_info, fs)
            self._safety.add(key)


def _window_taps(chunk: list[Item], fs: float) -> list[int]:
    """The differentiator window n_s of each point (0 for a controller without that section)."""
    from labrunner.control import factory

    try:
        return [d.n_s for d in factory.differentiators([c for _, _, c in chunk], fs, 0)]
    except (InvalidParameter, KeyError, TypeError):
        return [0] * len(chunk)


class _at:
    """Re-raise an :class:`InvalidParameter` with the grid point appended to its message."""

    def __init__(self, params: dict[str, Any]) -> None:
        self.params = params

    def __enter__(self) -> None:
        return None

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and issubclass(exc_type, InvalidParameter) and self.params:
            raise InvalidParameter(exc.field, f"{exc.message} (at grid point {canonical_json(self.params)})") from None


def _window_starts(section: Any) -> list[tuple[str, float]]:
    """(name, t0 [s]) of the ``[metrics]`` windows of a point (validated when the file was read)."""
    if not section:
        return []
    from labrunner.metrics import parse_windows

    return [(name, t0) for name, (t0, _) in parse_windows(section).items()]
