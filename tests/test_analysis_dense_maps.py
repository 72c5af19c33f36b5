"""Maps too dense for a marker per cell are drawn as a raster of outcome cells (checked on the
artists and on the pixels), small maps keep their markers, and a map is sent to the drawing
process as its cells, not its runs."""

import pickle
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
import pytest
from matplotlib import colors
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PathCollection, QuadMesh

from labrunner.analysis.context import Context, Theories
from labrunner.analysis.figures import map_jobs
from labrunner.analysis.map_data import Axis, Grid, Points
from labrunner.analysis.maps import map_figure, sweep_figure
from labrunner.analysis.overlays import OverlayLine

#: The outcome codes (map_data.OUTCOMES), written out here as the reference.
CODE = {"planned": -1, "aborted": 0, "no-motion": 1, "completed": 2, "failed": 3, "oscillating": 4}


def _outcome(i: int, j: int, n_x: int) -> str:
    """The outcome of cell (row i, column j) of the reference grid: aborted on the left, a band of
    oscillating runs, no-motion and failed patches, a few cells not run."""
    if j < n_x // 4:
        return "aborted"
    if j == n_x // 4 or j == n_x // 4 + 1:
        return "oscillating"
    if i < 5 and j > n_x - 8:
        return "no-motion"
    if 10 <= i < 13 and 30 <= j < 34:
        return "failed"
    if i == 20 and j % 7 == 0:
        return "planned"
    return "completed"


def _table(n_x: int, n_y: int, seed: int = 0) -> tuple[pd.DataFrame, Axis, Axis, np.ndarray]:
    """A γ–k_p table of ``n_x`` × ``n_y`` runs in random order, its axes, and the (n_y, n_x)
    outcome names of its cells, laid out independently of :class:`Grid`."""
    g, kp = np.logspace(1, 3, n_x), np.logspace(-1, 3, n_y)
    names = np.array([[_outcome(i, j, n_x) for j in range(n_x)] for i in range(n_y)], dtype=object)
    rows = [
        {
            "controller.gamma": g[j],
            "controller.k_p": kp[i],
            "outcome": "completed" if names[i, j] == "oscillating" else names[i, j],
            "oscillating": 1.0 if names[i, j] == "oscillating" else 0.0,
            "rms_error": float(i + j) if names[i, j] in ("completed", "no-motion") else np.nan,
        }
        for i in range(n_y)
        for j in range(n_x)
    ]
    table = pd.DataFrame(rows).sample(frac=1.0, random_state=seed).reset_index(drop=True)
    return table, Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p"), names


def test_dense_map_is_a_raster_of_outcome_cells_with_the_right_colours():
    table, x, y, names = _table(60, 50)
    line = OverlayLine("limit", 200.0, None, "magenta", "-", "bound:x")  # between the cells' centres
    fig = map_figure(Grid.of(table, x, y, ["rms_error"]), "rms_error", title="t", colour_label="c", overlays=[line])
    ax = fig.axes[0]
    assert not [c for c in ax.collections if isinstance(c, PathCollection)]  # no markers
    layer = next(c for c in ax.collections if isinstance(c, QuadMesh) and c.get_gid() == "outcomes")
    codes = np.vectorize(CODE.get)(names)
    flat = np.isin(names, ["aborted", "no-motion", "failed", "oscillating"])
    drawn = layer.get_array()
    np.testing.assert_array_equal(np.ma.getmaskarray(drawn).reshape(codes.shape), ~flat)
    np.testing.assert_array_equal(np.ma.getdata(drawn).reshape(codes.shape)[flat], codes[flat])
    assert ax.get_lines()[0].get_zorder() > layer.get_zorder()  # the bounds on top
    legend = {t.get_text() for t in fig.legends[0].get_texts()}
    assert legend == {
        "aborted by the safety routine",
        "oscillating / at an input limit (detector)",
        "failed (error)",
        "no-motion (input too small): pale metric colour",
        "not run",
        "limit",
    }

    # the pixels at the cells' centres
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    metric = next(c for c in ax.collections if isinstance(c, QuadMesh) and c.get_gid() != "outcomes")
    viridis = matplotlib.colormaps["viridis"]

    def pixel(i: int, j: int, at: float | None = None) -> np.ndarray:
        px, py = ax.transData.transform((x.values[j] if at is None else at, y.values[i]))
        return rgba[int(round(rgba.shape[0] - py)), int(round(px)), :3] / 255.0

    def veiled(c) -> np.ndarray:
        return 0.55 * np.ones(3) + 0.45 * np.asarray(c[:3])

    expected = {
        "aborted": lambda i, j: colors.to_rgb("darkred"),
        "oscillating": lambda i, j: colors.to_rgb("orange"),
        "failed": lambda i, j: colors.to_rgb("dimgrey"),
        "planned": lambda i, j: colors.to_rgb("#d9d9d9"),
        "completed": lambda i, j: viridis(metric.norm(i + j))[:3],
        "no-motion": lambda i, j: veiled(viridis(metric.norm(i + j))),
    }
    for i, j in [(0, 0), (30, 10), (40, 15), (3, 16), (2, 55), (11, 31), (20, 28), (25, 40), (45, 50)]:
        np.testing.assert_allclose(pixel(i, j), expected[names[i, j]](i, j), atol=2 / 255, err_msg=names[i, j])
    np.testing.assert_allclose(pixel(30, 0, at=200.0), colors.to_rgb("magenta"), atol=2 / 255)  # the line on top


@pytest.mark.parametrize(("n_x", "n_y"), [(10, 10), (40, 25)])
def test_small_maps_keep_a_marker_per_run(n_x, n_y):
    table, x, y, names = _table(n_x, n_y)
    fig = map_figure(Grid.of(table, x, y, ["rms_error"]), "rms_error", title="t\nδ_t", colour_label="c")
    ax = fig.axes[0]
    assert not [c for c in ax.collections if c.get_gid() == "outcomes"]
    markers = {c.get_label(): c for c in ax.collections if isinstance(c, PathCollection)}
    assert sum(len(c.get_offsets()) for c in markers.values()) == (names != "planned").sum()
    i, j = np.nonzero(names == "aborted")
    assert sorted(map(tuple, markers["aborted by the safety routine"].get_offsets())) == sorted(
        zip(x.values[j], y.values[i])
    )


def test_a_map_goes_to_the_drawing_process_as_its_cells(tmp_path: Path):
    """The maps' data pickled for the drawing child: a byte of outcome and 8 bytes a metric per
    cell, not the runs' coordinates, outcomes and metrics (32 bytes and more a run)."""
    table, x, y, _ = _table(200, 150)
    table["input_energy"] = table["rms_error"] ** 2
    ctx = Context(tmp_path, tmp_path / "report", None, "", ["controller.gamma", "controller.k_p"], {})
    jobs = map_jobs(table, ctx, Theories(None))
    assert [j.path.name for j in jobs] == ["map_rms_error.png", "map_input_energy.png"]
    cells = 200 * 150
    assert len(pickle.dumps(jobs)) <= cells * (1 + 8 * 2) + 20_000
    grid = jobs[0].args[0]
    assert grid.outcome.shape == (150, 200) and grid.outcome.dtype == np.int8


def test_a_dense_sweep_draws_completed_runs_as_its_line():
    """2000 runs over one axis: the line shows the completed runs (a marker each would hide it),
    markers the aborted ones; 20 runs keep a marker each."""
    for n, dense in ((2000, True), (20, False)):
        g = np.logspace(1, 3, n)
        aborted = g < 40
        t = pd.DataFrame(
            {
                "controller.gamma": g,
                "outcome": np.where(aborted, "aborted", "completed"),
                "rms_error": np.where(aborted, np.nan, 1 / g),
                "rms_error_until_abort": np.where(aborted, 2.0, np.nan),
            }
        )
        x = Axis("controller.gamma", g, True, "γ")
        fig = sweep_figure(Points.of(t, list(t.columns.drop("outcome"))), x, [("rms_error", "RMS")], title="s")
        ax = fig.axes[0]
        markers = {c.get_label(): len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection)}
        assert markers.get("aborted by the safety routine") == aborted.sum()
        assert ("completed" in markers) is not dense
        assert ([line.get_label() for line in ax.get_lines()] == ["completed"]) is dense
        np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), 1 / g[~aborted])
