"""Stability-boundary refinement: a coarse grid, then only the cells whose corners disagree.

The thesis draws its stability boundaries from full grids (Figs. 3.10, 3.14: 17 × 17 and 17 × 11
runs). The boundary between completed, aborted (safety trip) and no-motion runs is a curve, so
most cells of a full grid have four equal corners and tell nothing new. This procedure runs a
coarse ``coarse × coarse`` grid, then ``levels`` times splits every *mixed* cell (corners of more
than one outcome class) into four and runs the new corners (edge midpoints and centre) of all
mixed cells in one round. The result is every mixed cell at the resolution of the full grid with
N = (coarse − 1)·2^levels + 1 points per axis, for a number of runs that grows with the boundary's
length instead of its area. It finds the same boundary cells as the full grid wherever each
boundary feature crosses a coarse cell's corners (no island smaller than a coarse cell).

Fine lattice values are those of the grid axis ``{ log10 | linspace = [a, b], num = N }``
(:func:`labrunner.campaign.grid.parse_axis`), so a refined point has the id of the same point of
the full-grid campaign of the same name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from labrunner.campaign.grid import Axis, parse_axis
from labrunner.campaign.guided import Plan, Procedure, Result, Table, ask
from labrunner.errors import InvalidParameter

Cell = tuple[int, int]  # lower-left fine-lattice index (i along x, j along y)


def mixed(cell: Cell, stride: int, classes: Mapping[Cell, str]) -> bool:
    """Whether the cell with lower-left corner ``cell`` and side ``stride`` has corners of more than one class."""
    i, j = cell
    return len({classes[(i + di, j + dj)] for di in (0, stride) for dj in (0, stride)}) > 1


def boundary_cells(classes: Mapping[Cell, str], n: int) -> list[Cell]:
    """Mixed unit cells of a full n × n lattice of outcome classes (the reference for refinement)."""
    return sorted(c for c in ((i, j) for i in range(n - 1) for j in range(n - 1)) if mixed(c, 1, classes))


@dataclass(frozen=True)
class Refine(Procedure):
    """Boundary refinement over two axes of the campaign (``[guided.axes]``)."""

    name = "refine"
    x: Axis  # fine lattice along x
    y: Axis
    coarse: int
    levels: int

    @classmethod
    def from_table(cls, t: Table, campaign: Any) -> Refine:
        coarse = t.integer("coarse", 9, 2, 1000)
        levels = t.integer("levels", 2, 1, 10)
        table = t.raw("axes")
        if not isinstance(table, Mapping) or len(table) != 2:
            raise InvalidParameter(
                "guided.axes",
                f'must be a table of two axes, e.g. "controller.gamma" = {{ log10 = [0.0, 4.0] }}, got {table!r}',
            )
        n = (coarse - 1) * 2**levels + 1
        if n * n > 1_000_000:
            raise InvalidParameter("guided.levels", f"gives a {n} × {n} lattice; at most 1000 × 1000")
        axes = []
        for key, spec in table.items():
            field = f'guided.axes."{key}"'
            if "." not in key or key.split(".", 1)[0] not in ("controller", "differentiator", "reference", "safety"):
                raise InvalidParameter(field, "must be a dotted key of a run section, e.g. controller.k_p")
            if not isinstance(spec, Mapping) or set(spec) - {"log10", "linspace"} or len(spec) != 1:
                raise InvalidParameter(
                    field, "must be { log10 = [a, b] } or { linspace = [a, b] } (num follows from coarse and levels)"
                )
            axes.append(parse_axis(field, key, {**spec, "num": n}))
        return cls(axes[0], axes[1], coarse, levels)

    @property
    def size(self) -> int:
        """Points per axis of the fine lattice."""
        return len(self.x.values)

    def point(self, cell: Cell) -> dict[str, Any]:
        return {self.x.key: self.x.values[cell[0]], self.y.key: self.y.values[cell[1]]}

    def plan(self) -> Plan:
        n, stride = self.size, 2**self.levels
        classes: dict[Cell, str] = {}

        def run(stage: str, cells: list[Cell]):
            todo = list(dict.fromkeys(c for c in cells if c not in classes))
            if todo:
                answers = yield ask(stage, *(self.point(c) for c in todo))
                classes.update((c, o.status) for c, o in zip(todo, answers))

        yield from run(
            f"coarse {self.coarse} × {self.coarse}", [(i, j) for i in range(0, n, stride) for j in range(0, n, stride)]
        )
        cells = [(i, j) for i in range(0, n - 1, stride) for j in range(0, n - 1, stride)]
        runs = {"coarse": len(classes)}
        for level in range(1, self.levels + 1):
            split = [c for c in cells if mixed(c, stride, classes)]
            stride //= 2
            cells = [(i + a * stride, j + b * stride) for i, j in split for a in (0, 1) for b in (0, 1)]
            before = len(classes)
            yield from run(
                f"level {level}: {len(split)} mixed cells",
                [(i + a * stride, j + b * stride) for i, j in split for a in (0, 1, 2) for b in (0, 1, 2)],
            )
            runs[f"level {level}"] = len(classes) - before
        found = sorted(c for c in cells if mixed(c, 1, classes))
        detail = {
            "boundary_cells": [list(c) for c in found],
            "resolution": [n, n],
            "full_grid_runs": n * n,
            "runs": len(classes),
            "runs_per_level": runs,
        }
        return Result(
            None, f"{len(found)} boundary cells at {n} × {n} from {len(classes)} runs (full grid: {n * n})", detail
        )

    def max_runs(self) -> int:
        return self.size**2

    def corners(self) -> list[dict[str, Any]]:
        last = self.size - 1
        return [self.point((i, j)) for i in (0, last) for j in (0, last)]

    def axes(self) -> tuple[tuple[Axis, ...], ...]:
        return ((self.x,), (self.y,))

    def describe(self) -> str:
        n = self.size
        return (
            f"boundary refinement of {self.x.key} × {self.y.key}: coarse {self.coarse} × {self.coarse}, "
            f"{self.levels} levels → {n} × {n} (a full grid: {n * n} runs)"
        )
