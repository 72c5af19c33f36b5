"""What a map or a sweep plot shows, as plain numpy data: the grid axes, their labels and cells;
a map's cells as images (:class:`Grid`: each cell's outcome code and metric values), a sweep's
runs as points (:class:`Points`: each run's coordinate, outcome code and metrics).

No pandas and no matplotlib: the parent of ``analyse`` builds these from its table and sends them
to the child that draws (:mod:`labrunner.analysis.maps`), which then needs neither the table nor
pandas (~0.3 s), and the parent never loads matplotlib (~0.2 s) when a child draws. A map is sent
as its cells, not its runs: what the child receives and draws is bounded by the grid (one byte and
8 bytes a metric per cell), whatever the number of runs behind it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: Observed outcomes (:func:`labrunner.analysis.agreement.observed_outcome`) in code order: a
#: run's or a cell's outcome is stored as its index here (int8), :data:`NO_RUN` where there is none.
OUTCOMES = ("aborted", "no-motion", "completed", "failed", "oscillating")
NO_RUN = -1
#: Codes of the outcomes whose metric describes the whole run and may colour a cell.
COLOURED = (OUTCOMES.index("completed"), OUTCOMES.index("no-motion"))


def outcome_codes(table: Any) -> np.ndarray:
    """Each row's observed outcome as its :data:`OUTCOMES` code (int8; :data:`NO_RUN` for planned
    and claimed points): one byte a run."""
    from labrunner.analysis.agreement import observed_outcome

    observed = observed_outcome(table)
    codes = np.full(len(observed), NO_RUN, dtype=np.int8)
    for code, name in enumerate(OUTCOMES):
        codes[(observed == name).to_numpy(dtype=bool)] = code
    return codes


@dataclass(frozen=True)
class Axis:
    """One grid axis: the dotted campaign key, its values, log10 spacing, a label with its unit."""

    key: str
    values: np.ndarray
    log: bool
    label: str


@dataclass(frozen=True)
class Points:
    """One entry per run: ``columns`` (grid keys and metrics → float arrays) and ``outcome`` (the
    observed outcome's :data:`OUTCOMES` code: "oscillating" for a completed run the detector flags)."""

    columns: Mapping[str, np.ndarray]
    outcome: np.ndarray

    @classmethod
    def of(cls, table: Any, columns: Iterable[str]) -> Points:
        """The ``columns`` of a metrics table (those it has) and its observed outcomes."""
        keep = dict.fromkeys(c for c in columns if c in table.columns)
        return cls({c: table[c].to_numpy(dtype=float) for c in keep}, outcome_codes(table))

    def __getitem__(self, column: str) -> np.ndarray:
        return self.columns[column]

    def __contains__(self, column: str) -> bool:
        return column in self.columns

    def where(self, mask: np.ndarray) -> Points:
        """The runs where ``mask`` (boolean, or an index array in the order wanted) holds."""
        return Points({c: v[mask] for c, v in self.columns.items()}, self.outcome[mask])

    def coloured(self) -> np.ndarray:
        """Whether each run's metric may colour its cell (:data:`COLOURED`)."""
        return np.isin(self.outcome, COLOURED)


#: Runs placed on a map's grid at a time (:meth:`Grid.of`).
ROWS_AT_A_TIME = 100_000


@dataclass(frozen=True)
class Grid:
    """A map's cells: its axes, each cell's outcome code (``outcome``, (len(y), len(x)) int8,
    :data:`NO_RUN` where no run lies) and, per metric column, its value in each cell (``images``,
    float64, NaN where the cell must stay uncoloured: no run, or an outcome whose metric covers
    only part of a run or a limit cycle). A cell holds the last run the table places in it."""

    x: Axis
    y: Axis
    outcome: np.ndarray
    images: Mapping[str, np.ndarray]

    @classmethod
    def of(cls, table: Any, x: Axis, y: Axis, columns: Iterable[str]) -> Grid:
        """The cells of a metrics table's runs (each placed at its nearest axis values) and of its
        ``columns`` (those it has), filled :data:`ROWS_AT_A_TIME` rows at a time: the
        temporaries of placing 10^6 runs would be ~70 MB at once."""
        columns = list(dict.fromkeys(c for c in columns if c in table.columns))
        outcome = np.full((len(y.values), len(x.values)), NO_RUN, dtype=np.int8)
        images = {column: np.full(outcome.shape, np.nan) for column in columns}
        codes = outcome_codes(table)
        for start in range(0, len(table), ROWS_AT_A_TIME):
            rows = slice(start, start + ROWS_AT_A_TIME)
            xs, ys = (table[axis.key].to_numpy(dtype=float)[rows] for axis in (x, y))
            placed = np.isfinite(xs) & np.isfinite(ys)
            iy, ix = grid_index(ys[placed], y.values), grid_index(xs[placed], x.values)
            outcome[iy, ix] = codes[rows][placed]
            coloured = np.isin(codes[rows][placed], COLOURED)
            for column in columns:
                value = table[column].to_numpy(dtype=float)[rows][placed]
                ok = coloured & np.isfinite(value)
                images[column][iy[ok], ix[ok]] = value[ok]
        return cls(x, y, outcome, images)

    def runs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, outcome code) of each cell that holds a run, the centres of the cells."""
        iy, ix = np.nonzero(self.outcome != NO_RUN)
        return self.x.values[ix], self.y.values[iy], self.outcome[iy, ix]


def gain_units(order: int, output_unit: str, input_unit: str) -> dict[str, str]:
    """SI units of γ, k_p, k_d for an MFC law of ``order`` (1: ẏ = f + ρu; 2: ÿ = f + ρu)."""
    gamma = f"{output_unit}/({input_unit}·s)" if order == 1 else f"{output_unit}/({input_unit}·s²)"
    if output_unit == "rad/s" and order == 1:
        gamma = f"rad/({input_unit}·s²)"
    return {"controller.gamma": gamma, "controller.k_p": "1/s" if order == 1 else "1/s²", "controller.k_d": "1/s"}


_NAMES = {
    "controller.gamma": "input gain γ",
    "controller.k_p": "proportional gain k_p",
    "controller.k_d": "differential gain k_d",
    "differentiator.alpha": "α",
    "differentiator.beta": "β",
    "differentiator.omega_c": "cutoff ω_c",
    "differentiator.N": "N",
    "fs": "sampling frequency f_s",
}
_UNITS = {"differentiator.omega_c": "rad/s", "fs": "Hz"}


def axis_label(key: str, units: dict[str, str] | None = None) -> str:
    """Readable label with its SI unit for a dotted campaign key (thesis symbols)."""
    unit = {**_UNITS, **(units or {})}.get(key)
    name = _NAMES.get(key, key.removeprefix("rig_parameters."))  # a rig parameter by its rig file's name
    return f"{name} [{unit}]" if unit else name


def is_log_spaced(values: np.ndarray) -> bool:
    """Whether sorted axis values (a grid axis of listed values) are evenly spaced in log10 and span > 1 decade."""
    v = np.asarray(values, dtype=float)
    if v.size < 2 or np.any(v <= 0) or v[-1] / v[0] <= 10:
        return False
    steps = np.diff(np.log10(v))
    return v.size == 2 or bool(np.allclose(steps, steps[0], rtol=1e-6))


def cell_edges(values: np.ndarray, log: bool) -> np.ndarray:
    """Edges of the cells centred on sorted ``values`` (geometric midpoints on a log axis)."""
    v = np.log10(values) if log else np.asarray(values, dtype=float)
    if v.size == 1:
        half = 0.5 if log else max(abs(v[0]) * 0.1, 0.5)
        edges = np.array([v[0] - half, v[0] + half])
    else:
        mid = 0.5 * (v[1:] + v[:-1])
        edges = np.concatenate([[2 * v[0] - mid[0]], mid, [2 * v[-1] - mid[-1]]])
    return 10.0**edges if log else edges


def grid_index(values: np.ndarray, axis_values: np.ndarray) -> np.ndarray:
    """Index of each value on the (sorted) axis, matched to the nearest axis value."""
    ref = np.log10(axis_values) if np.all(axis_values > 0) else axis_values
    val = np.log10(values) if np.all(axis_values > 0) else values
    pos = np.clip(np.searchsorted(ref, val), 1, max(len(ref) - 1, 1))
    if len(ref) == 1:
        return np.zeros(len(values), dtype=int)
    left, right = ref[pos - 1], ref[pos]
    return np.where(np.abs(val - left) <= np.abs(val - right), pos - 1, pos)
