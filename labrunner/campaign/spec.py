"""Campaign files (TOML) → a validated :class:`Campaign`, its points, and the static checks.

A campaign file has the sections ``[campaign]`` (name, description, rig, fs [Hz], duration [s],
seed), the pass-through sections of a run (``[controller]``, ``[differentiator]``,
``[reference]``, ``[safety]``, ``[rig_parameters]``), ``[grid]`` (axes, see
:mod:`labrunner.campaign.grid`) and ``[derived]`` (safe expressions, see
:mod:`labrunner.campaign.expressions`). Every error names its key path. :func:`load` checks every
point against the static limits (α vs derivative order, ω_c vs Nyquist, finite gains, the rig's
f_s range and safety keys) before anything is created, so a bad grid fails in seconds, not after
the first hundred runs.
"""

from __future__ import annotations

import dataclasses
import hashlib
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from labrunner import inputfile
from labrunner.campaign import expressions, grid as gridmod, metadata as metadata_mod
from labrunner.campaign.checks import MAX_SEED, StaticChecker, batch_key, batch_key_of, lookup_point
from labrunner.campaign.config_tree import NameView, copy_tree, dotted_keys, set_key
from labrunner.campaign.grid import Grid, canonical_json, point_id
from labrunner.errors import InvalidParameter, check_finite, check_number, check_positive
from labrunner.rigs import config as rigconfig
from labrunner.rigs.base import RigConfig, RigInfo
from labrunner.rigs.kinds import rig_class

SECTIONS = ("controller", "differentiator", "reference", "safety", "rig_parameters")
CAMPAIGN_KEYS = ("name", "description", "rig", "fs", "duration", "seed")
GRID_CAMPAIGN_KEYS = ("fs", "duration", "seed")  # campaign keys a grid may vary
OPTIONAL_SECTIONS = ("metrics",)  # in a run's configuration only where the file has them
TOP_LEVEL = ("campaign", *SECTIONS, *OPTIONAL_SECTIONS, "grid", "guided", "derived", "logging", "metadata")
LOGGING_KEYS = ("samples_hz", "precision")  # [logging]: how the run logs are written
PRECISIONS = ("float64", "float32")  # [logging] precision: how the logs store each sample's values
NAME_RE = re.compile(r"[a-z0-9_-]{1,64}")
_PROJECT_MARKERS = ("pyproject.toml", "rigs", ".git")


@dataclass(frozen=True)
class PlannedPoint:
    """A grid point: grid order ``seq``, stable ``id``, its ``parameters`` (grid + derived values)."""

    seq: int
    id: str
    parameters: dict[str, Any]
    batch_key: str  # points with equal keys may share a batch: rig, fs, duration, controller kind


@dataclass(frozen=True)
class Campaign:
    """A validated campaign. ``base`` holds the pass-through sections before grid values apply."""

    name: str
    description: str
    rig: str  # as written: a rig name or a path relative to the campaign file
    rig_path: Path | None  # the resolved rig file when ``rig`` is a path
    fs: float
    duration: float | None
    seed: int
    base: Mapping[str, Mapping[str, Any]]
    grid: Grid
    derived: tuple[tuple[str, expressions.Expression], ...]
    source: str
    source_path: Path | None
    project_root: Path
    rig_info: RigInfo = field(repr=False)
    rig_config: RigConfig = field(repr=False, compare=False)  # the validated rig file
    rig_safety: Mapping[str, Any] = field(default_factory=dict, repr=False)
    guided: Any = None  # a labrunner.campaign.guided.Procedure for a guided campaign ([guided] instead of [grid])
    logging: Mapping[str, Any] = field(default_factory=dict)  # [logging], validated: samples_hz [Hz], precision
    metadata: Mapping[str, Any] = field(default_factory=dict)  # [metadata]: the user's own fields (.metadata)
    rig_link: Mapping[str, str] = field(default_factory=dict)  # the command line's --port etc. (rigconfig.LINK_KEYS)

    @property
    def rig_ref(self) -> str:
        """What the rig registry loads: the absolute rig file, or the rig's name."""
        return str(self.rig_path) if self.rig_path else self.rig

    @property
    def rig_search(self) -> tuple[str, ...]:
        return tuple(str(p) for p in rigconfig.default_search(self.project_root))

    @property
    def size(self) -> int:
        """Points of the grid; of a guided campaign, the most runs its procedure can ask for."""
        return self.grid.size if self.guided is None else self.guided.max_runs()

    def resolve(self, parameters: Mapping[str, Any]) -> dict[str, Any]:
        """The full run configuration of one point: base sections with its parameters set."""
        config: dict[str, Any] = {s: copy_tree(dict(self.base.get(s, {}))) for s in SECTIONS}
        config.update({s: copy_tree(dict(self.base[s])) for s in OPTIONAL_SECTIONS if self.base.get(s)})
        config["campaign"] = {
            "name": self.name,
            "rig": self.rig,
            "fs": self.fs,
            "duration": self.duration,
            "seed": self.seed,
        }
        for key, value in parameters.items():
            set_key(config, key, value)
        return config

    def expand(self, params: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """(parameters with the derived values added, resolved config) of one point."""
        config = self.resolve(params)
        for key, expr in self.derived:
            value = expr.evaluate(NameView(config, self.rig_info.constants))
            set_key(config, key, value)
            params[key] = value
        return params, config

    def points(self) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
        """(parameters, config) of every point in grid order, derived values evaluated."""
        for params in self.grid.points():
            yield self.expand(params)


def project_root(path: Path) -> Path:
    """Nearest ancestor of ``path`` holding pyproject.toml, rigs/ or .git; else its own folder."""
    start = path.resolve().parent
    for folder in (start, *start.parents):
        if any((folder / m).exists() for m in _PROJECT_MARKERS):
            return folder
    return start


def _require(field_name: str, value: Any, kind: type | tuple[type, ...], what: str) -> Any:
    if isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple) else (kind,)):
        raise InvalidParameter(field_name, f"must be {what}, got {value!r}")
    if not isinstance(value, kind):
        raise InvalidParameter(field_name, f"must be {what}, got {type(value).__name__} {value!r}")
    return value


def parse(text: str, *, source_path: Path | None = None) -> dict[str, Any]:
    """TOML text → dict, with a one-line error naming the line on a syntax error."""
    return inputfile.loads_toml(text, source_path.name if source_path else "campaign")


def _resolve_rig(value: Any, source_path: Path | None, root: Path) -> tuple[str, Path | None]:
    _require("campaign.rig", value, str, "a rig name or a path to a rig file")
    if NAME_RE.fullmatch(value):
        return value, None
    bases = ([source_path.resolve().parent] if source_path else []) + [root]
    candidates = [(base / value).resolve() for base in bases]  # next to the campaign file, else in the project
    path = next((c for c in candidates if c.is_file()), candidates[0])
    if not path.is_relative_to(root.resolve()):
        raise InvalidParameter("campaign.rig", f"path {value!r} is outside the project {str(root)!r}")
    if path.suffix != ".toml" or not path.is_file():
        raise InvalidParameter("campaign.rig", f"{value!r} is neither a rig name ([a-z0-9_-]+) nor a rig .toml file")
    return value, path


def from_text(
    text: str, *, source_path: Path | None = None, root: Path | None = None, link: Mapping[str, str] | None = None
) -> Campaign:
    """Parse and validate a campaign (structure, keys, grid, derived, rig); no per-point checks.
    ``link``: a real rig's port or CAN interface and channel instead of its rig file's."""
    root = (root or (project_root(source_path) if source_path else Path.cwd())).resolve()
    doc = parse(text, source_path=source_path)
    unknown = sorted(set(doc) - set(TOP_LEVEL))
    if unknown:
        raise InvalidParameter(unknown[0], f"unknown section; allowed: {', '.join(TOP_LEVEL)}")
    for section in (*SECTIONS, "campaign", "derived", "logging"):
        if section in doc:
            _require(section, doc[section], dict, "a table")
    head = doc.get("campaign")
    if head is None:
        raise InvalidParameter("campaign", "section is missing (needs at least name and rig)")
    bad = sorted(set(head) - set(CAMPAIGN_KEYS))
    if bad:
        raise InvalidParameter(
            f"campaign.{bad[0]}", f"unknown key; allowed: {', '.join(CAMPAIGN_KEYS)}; {metadata_mod.HINT}"
        )
    for key in ("name", "rig"):
        if key not in head:
            raise InvalidParameter(f"campaign.{key}", "is required")
    name = _require("campaign.name", head["name"], str, "a string")
    if not NAME_RE.fullmatch(name):
        raise InvalidParameter("campaign.name", f"must match [a-z0-9_-]+ (at most 64 characters), got {name!r}")
    description = _require("campaign.description", head.get("description", ""), str, "a string")
    rig, rig_path = _resolve_rig(head["rig"], source_path, root)
    link = {k: v for k, v in (link or {}).items() if v is not None}
    rig_config = load_rig_file(rig_path or rig, root, link)
    info = rigconfig.rig_info(rig_config)
    rig_params = tuple(rig_class(rig_config.kind).overridable())
    fs = check_positive("campaign.fs", head["fs"], strict=True) if "fs" in head else float(info.fs_default)
    info.check_fs(fs, "campaign.fs")
    duration = check_positive("campaign.duration", head["duration"], strict=True) if "duration" in head else None
    seed = _require("campaign.seed", head.get("seed", 0), int, "an integer")
    if not 0 <= seed <= MAX_SEED:
        raise InvalidParameter("campaign.seed", f"must be an integer in [0, 2**63 - 1], got {seed}")
    base = {s: doc.get(s, {}) for s in SECTIONS}
    for section in SECTIONS:
        _check_finite_leaves(section, base[section])
    if "metrics" in doc:  # named windows [t0, t1] of the metrics (labrunner.metrics)
        from labrunner.metrics import parse_windows

        parse_windows(_require("metrics", doc["metrics"], dict, "a table"))
        base["metrics"] = doc["metrics"]
    settable = {f"campaign.{k}" for k in GRID_CAMPAIGN_KEYS} | {k for s in SECTIONS for k in dotted_keys(base[s], s)}

    def check_key(field_name: str, key: str) -> None:
        section = key.split(".", 1)[0]
        if key.startswith("campaign."):
            if key not in settable:
                raise InvalidParameter(field_name, f"only campaign.{{{', '.join(GRID_CAMPAIGN_KEYS)}}} may vary")
        elif section not in SECTIONS or "." not in key:
            raise InvalidParameter(
                field_name, f"must be a dotted key in one of {', '.join(SECTIONS)} (or campaign.fs/duration/seed)"
            )
        elif section == "rig_parameters" and key.split(".", 2)[1] not in rig_params:
            has = f"it has {', '.join(rig_params)}" if rig_params else "it has no per-run parameters"
            raise InvalidParameter(field_name, f"rig {rig!r} has no parameter {key.split('.', 2)[1]!r}; {has}")

    for key in base["rig_parameters"]:
        check_key(f"rig_parameters.{key}", f"rig_parameters.{key}")
    fixed = {k: check_number(f"rig_parameters.{k}", v) for k, v in base["rig_parameters"].items()}
    rig_class(rig_config.kind).check_overrides(rig_config, fixed, 1, "rig_parameters")  # grid values: in plan()
    if "grid" in doc and "guided" in doc:
        raise InvalidParameter(
            "guided", "a campaign has either [grid] (a fixed grid) or [guided] (a tuning procedure), not both"
        )
    grid = gridmod.parse_grid(doc["grid"], check_key) if "grid" in doc else Grid()
    derived: list[tuple[str, expressions.Expression]] = []
    known = set(settable) | set(grid.keys) | set(info.constants)
    for key, source in _derived_items(doc.get("derived", {})):
        check_key(f'derived."{key}"', key)
        if key in grid.keys:
            raise InvalidParameter(f'derived."{key}"', "is also a grid axis; a key is either swept or derived")
        derived.append((key, expressions.parse(f'derived."{key}"', source, known)))
        known.add(key)
    campaign = Campaign(
        name=name,
        description=description,
        rig=rig,
        rig_path=rig_path,
        fs=fs,
        duration=duration,
        seed=seed,
        base=base,
        grid=grid,
        derived=tuple(derived),
        source=text,
        source_path=source_path,
        project_root=root,
        rig_info=info,
        rig_safety=dict(rig_config.safety),
        rig_config=rig_config,
        logging=_logging(doc.get("logging", {})),
        metadata=metadata_mod.parse(doc.get("metadata", {})),
        rig_link=link,
    )
    if "guided" in doc:  # the procedure's axes stand in for a grid (analysis maps, derived keys)
        from labrunner.campaign import procedures

        procedure = procedures.parse(doc["guided"], campaign)
        campaign = dataclasses.replace(campaign, guided=procedure, grid=Grid(procedure.axes()))
    return campaign


def _logging(table: Mapping[str, Any]) -> dict[str, Any]:
    """``[logging]``: ``samples_hz`` > 0 thins the logs' per-sample channel /run/samples to about
    that rate (at or above f_s: every sample); the lossless /run/blocks always keep every sample.
    ``precision`` = ``float32`` stores every signal rounded to float32 (default ``float64``: exact)."""
    bad = sorted(set(table) - set(LOGGING_KEYS))
    if bad:
        raise InvalidParameter(f"logging.{bad[0]}", f"unknown key; allowed: {', '.join(LOGGING_KEYS)}")
    out: dict[str, Any] = {}
    if "samples_hz" in table:
        out["samples_hz"] = check_positive("logging.samples_hz", table["samples_hz"], strict=True)
    if "precision" in table:
        if table["precision"] not in PRECISIONS:
            raise InvalidParameter(
                "logging.precision", f"must be one of {', '.join(PRECISIONS)}, got {table['precision']!r}"
            )
        out["precision"] = table["precision"]
    return out


def _check_finite_leaves(path: str, node: Any) -> None:
    """Refuse NaN and ±inf anywhere in a section (TOML allows them; no setting means them)."""
    if isinstance(node, Mapping):
        for key, value in node.items():
            _check_finite_leaves(f"{path}.{key}", value)
    elif isinstance(node, list):
        for value in node:
            _check_finite_leaves(path, value)
    elif isinstance(node, float):
        check_finite(path, node, "a finite number")


def _derived_items(table: Mapping[str, Any], prefix: str = "") -> Iterator[tuple[str, Any]]:
    for key, value in table.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, Mapping):
            yield from _derived_items(value, path)
        else:
            yield path, value


def load_rig_file(ref: str | Path, root: Path, link: Mapping[str, str] | None = None) -> RigConfig:
    """The campaign's rig file, validated, without opening the rig (``link``: see :func:`from_text`).

    Its errors keep the loader's own field (``rigs/bad.toml: parameters.a``); only a rig file that
    cannot be found is reported as ``campaign.rig``.
    """
    try:
        return rigconfig.load_rig_config(str(ref), search=rigconfig.default_search(root), link=link)
    except InvalidParameter as exc:
        if exc.field == "rig":
            raise InvalidParameter("campaign.rig", exc.message) from None
        raise


def load(path: str | Path, *, root: Path | None = None, link: Mapping[str, str] | None = None) -> Campaign:
    """Read and validate a campaign file (structure only; see :func:`plan` for the per-point checks)."""
    path = Path(path)
    return from_text(inputfile.read_text(path, "FILE", "campaign file"), source_path=path, root=root, link=link)


def plan(campaign: Campaign) -> tuple[list[PlannedPoint], str]:
    """Expand and statically check every point; return the points in grid order and the plan checksum.

    The checksum covers the resolved configuration of every point (not the file's bytes), so a
    comment edit keeps a campaign resumable while any change of what would run does not.
    """
    if campaign.guided is not None:
        return _plan_guided(campaign)
    checker = StaticChecker(campaign.rig_config)
    checked: list[tuple[int, dict[str, Any], float, str]] = []

    def accept(items) -> None:
        for (seq, params, config), duration in items:
            config["campaign"]["duration"] = duration
            checked.append((seq, params, duration, hashlib.sha256(canonical_json(config).encode()).hexdigest()))

    for seq, (params, config) in enumerate(campaign.points()):
        accept(checker.add(seq, params, config))
    accept(checker.flush())
    checked.sort(key=lambda c: c[0])
    points: list[PlannedPoint] = []
    base = campaign.resolve({})
    for seq, params, duration, _ in checked:  # batch keys once every batch-common key is known
        found = checker.choices(params, lambda p=params: campaign.resolve(p))  # known by now: not resolved
        values = [lookup_point(params, base, k) for k in checker.split]
        key = batch_key_of(campaign.rig, params.get("campaign.fs", campaign.fs), duration, found, values)
        points.append(PlannedPoint(seq, point_id(campaign.name, params), params, key))
    gridmod.check_unique([p.id for p in points], [p.parameters for p in points])
    from labrunner.rigs.device.plan import check_placement

    check_placement(campaign, points)  # a loop the rig's link or device cannot carry
    digest = hashlib.sha256(canonical_json({"name": campaign.name, "rig": campaign.rig}).encode())
    for *_, d in checked:
        digest.update(d.encode())
    return points, digest.hexdigest()


def check_points(campaign: Campaign, points: Sequence[Mapping[str, Any]], first_seq: int = 0) -> list[PlannedPoint]:
    """Statically check points as :func:`plan` checks a grid (a guided campaign's rounds); their ids
    are those of the points as proposed, their parameters include ``[derived]`` values."""
    checker = StaticChecker(campaign.rig_config)
    checked: dict[int, tuple[dict[str, Any], dict[str, Any], float]] = {}
    for n, point in enumerate(points):
        params, config = campaign.expand(dict(point))
        for (seq, p, c), duration in checker.add(n, params, config):
            checked[seq] = (p, c, duration)
    for (seq, p, c), duration in checker.flush():
        checked[seq] = (p, c, duration)
    out = []
    for n, point in enumerate(points):
        params, config, duration = checked[n]
        config["campaign"]["duration"] = duration
        out.append(
            PlannedPoint(
                first_seq + n, point_id(campaign.name, point), params, batch_key(campaign.rig, config, checker.split)
            )
        )
    return out


def _plan_guided(campaign: Campaign) -> tuple[list[PlannedPoint], str]:
    """A guided campaign's first round and plan checksum (procedure, base configuration, the checked
    extreme points of the search space and the first round); later rounds follow from the outcomes
    (:mod:`labrunner.campaign.guided_run`)."""
    from labrunner.campaign.guided import advance

    procedure = campaign.guided
    corners = check_points(campaign, procedure.corners())
    first = check_points(campaign, list(advance(procedure, campaign.name, {}).next))
    digest = hashlib.sha256(
        canonical_json(
            {
                "name": campaign.name,
                "rig": campaign.rig,
                "procedure": procedure.identity(),
                "base": campaign.resolve({}),
                "points": [[p.parameters, p.batch_key] for p in (*corners, *first)],
            }
        ).encode()
    )
    return first, digest.hexdigest()
