"""Maps render with the thesis's markers and the overlay lines (checked on the Axes artists)."""

import numpy as np
import pandas as pd
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PathCollection, QuadMesh
from matplotlib.lines import Line2D

from labrunner.analysis.map_data import Axis, Grid, Points, cell_edges, is_log_spaced
from labrunner.analysis.maps import map_figure, sweep_figure
from labrunner.analysis.overlays import OverlayLine


def _points(table: pd.DataFrame) -> Points:
    return Points.of(table, [c for c in table.columns if c != "outcome"])


def _table():
    g, kp = np.logspace(0, 4, 5), np.logspace(-1, 3, 4)
    G, K = np.meshgrid(g, kp)
    status = np.full(G.shape, "completed", dtype=object)
    status[0, -1] = "no-motion"
    status[-1, 0] = "aborted"
    status[-1, 1] = "failed"
    return (
        g,
        kp,
        pd.DataFrame(
            {
                "controller.gamma": G.ravel(),
                "controller.k_p": K.ravel(),
                "outcome": status.ravel(),
                "rms_error": (G / K).ravel(),
            }
        ),
    )


def test_cell_edges_are_geometric_midpoints_on_log_axes():
    edges = cell_edges(np.array([1.0, 10.0, 100.0]), log=True)
    np.testing.assert_allclose(edges, [10**-0.5, 10**0.5, 10**1.5, 10**2.5])
    np.testing.assert_allclose(cell_edges(np.array([0.0, 2.0]), log=False), [-1.0, 1.0, 3.0])


def test_log_spacing_detection():
    assert is_log_spaced(np.logspace(-1, 3, 17))
    assert not is_log_spaced(np.linspace(1, 100, 17))
    assert not is_log_spaced(np.array([1.0, 2.0, 4.0]))  # less than a decade


def test_grid_image_leaves_aborted_and_failed_cells_blank():
    g, kp, t = _table()
    x, y = Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p")
    z = Grid.of(t, x, y, ["rms_error"]).images["rms_error"]
    assert z.shape == (4, 5)
    assert np.isnan(z[-1, 0]) and np.isnan(z[-1, 1])
    assert z[0, -1] == pytest.approx(1e4 / 0.1)  # no-motion cells keep their colour
    assert z[1, 2] == pytest.approx(g[2] / kp[1])


def test_map_has_markers_overlays_colorbar_and_saves(tmp_path):
    g, kp, t = _table()
    x, y = Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p")
    dense = np.geomspace(0.5, 2e4, 50)
    lines = [
        OverlayLine("(2.46) max k_p", dense, 2 * dense, "red", "-", "bound:mfc1-motor:k_p_max"),
        OverlayLine("nominal input gain ρ = 108.55", 108.55, None, "white", "-", "nominal-gain"),
    ]
    fig = map_figure(
        Grid.of(t, x, y, ["rms_error"]), "rms_error", title="RMS", colour_label="RMS [rad/s]", overlays=lines
    )
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    assert any(isinstance(c, QuadMesh) for c in ax.collections)
    markers = {c.get_label(): c for c in ax.collections if isinstance(c, PathCollection)}
    assert set(markers) == {
        "aborted by the safety routine",
        "no-motion (input too small)",
        "completed",
        "failed (error)",
    }
    np.testing.assert_allclose(markers["aborted by the safety routine"].get_offsets(), [[g[0], kp[-1]]])
    assert markers["aborted by the safety routine"].get_facecolor()[0][:3] == pytest.approx((1, 0, 0))
    assert markers["no-motion (input too small)"].get_facecolor()[0][:3] == pytest.approx((1, 1, 1))
    assert len(markers["completed"].get_offsets()) == 20 - 3
    # the thesis's shapes (Figs. 3.10, 3.14): red triangle, white circle, black cross
    from matplotlib.markers import MarkerStyle

    for label, shape, face in [
        ("aborted by the safety routine", "^", (1, 0, 0)),
        ("no-motion (input too small)", "o", (1, 1, 1)),
        ("completed", "x", (0, 0, 0)),
    ]:
        style = MarkerStyle(shape)
        expected = style.get_path().transformed(style.get_transform()).vertices
        np.testing.assert_allclose(markers[label].get_paths()[0].vertices, expected)
        assert markers[label].get_facecolor()[0][:3] == pytest.approx(face)
    assert markers["aborted by the safety routine"].get_offsets().shape == (1, 2)
    assert markers["completed"].get_path_effects()  # white halo: visible on dark cells too
    np.testing.assert_allclose(markers["no-motion (input too small)"].get_offsets(), [[g[-1], kp[0]]])
    gids = {line.get_gid(): line for line in ax.get_lines() if isinstance(line, Line2D)}
    assert set(gids) == {"bound:mfc1-motor:k_p_max", "nominal-gain"}
    np.testing.assert_allclose(gids["nominal-gain"].get_xdata(), [108.55, 108.55])
    assert len(fig.axes) == 2  # the colour bar
    assert fig.legends and {t.get_text() for t in fig.legends[0].get_texts()} >= {
        "completed",
        r"(2.46) max $k_\mathrm{p}$",
    }
    path = tmp_path / "map.png"
    fig.savefig(path, dpi=100)
    from matplotlib.image import imread

    height, width = imread(path).shape[:2]
    assert width == 750 and 0.62 * 750 < height < 750  # the plot's 0.62 of the width, the title and legend


def test_sweep_plot_draws_markers_per_status():
    t = pd.DataFrame(
        {
            "controller.gamma": np.logspace(0, 3, 4),
            "outcome": ["aborted", "completed", "completed", "no-motion"],
            "rms_error": [5.0, 1.0, 2.0, 3.0],
            "input_energy": [1e4, 1e3, 5.0, 1.0],
        }
    )
    x = Axis("controller.gamma", t["controller.gamma"].to_numpy(), True, "γ")
    fig = sweep_figure(
        _points(t),
        x,
        [("rms_error", "RMS"), ("input_energy", "E(u)")],
        title="sweep",
        overlays=[OverlayLine("limit", 3.0, None, "red", "--", "bound:x")],
    )
    top, bottom = fig.axes
    labels = {c.get_label() for c in top.collections}
    assert labels == {"aborted by the safety routine", "no-motion (input too small)", "completed"}
    assert bottom.get_yscale() == "log" and top.get_xscale() == "log"
    assert [line.get_gid() for line in top.get_lines()].count("bound:x") == 1


def _pixels(fig) -> np.ndarray:
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba()).copy()


@pytest.mark.parametrize(
    ("x_log", "y_log", "span"),
    [(True, True, (0, 4)), (True, False, (-2, 1)), (False, False, (0, 2)), (True, True, (0.3, 0.8))],
)
def test_in_view_locators_draw_the_same_pixels(monkeypatch, x_log, y_log, span):
    """Maps and sweeps with InView locators on their log axes equal those drawn with matplotlib's
    own (ticks, labels, minor ticks, a log colour bar), and create fewer ticks."""
    import labrunner.analysis.maps as maps

    g = np.logspace(*span, 7) if x_log else np.linspace(1.0, 9.0, 7)
    kp = np.logspace(-1, 3, 5) if y_log else np.linspace(-3.0, 3.0, 5)
    G, K = np.meshgrid(g, kp)
    t = pd.DataFrame(
        {
            "controller.gamma": G.ravel(),
            "controller.k_p": K.ravel(),
            "outcome": "completed",
            "e": (G * (1.0 + K**2)).ravel(),
        }
    )
    x, y = Axis("controller.gamma", g, x_log, "γ"), Axis("controller.k_p", kp, y_log, "k_p")

    def draw(in_view: bool):
        if not in_view:
            monkeypatch.setattr(maps, "visible_ticks_only", lambda fig: None)
        figs = [
            map_figure(Grid.of(t, x, y, ["e"]), "e", title="map", colour_label="e", log_colour=True),
            sweep_figure(_points(t[t["controller.k_p"] == kp[0]]), x, [("e", "e")], title="sweep"),
        ]
        monkeypatch.undo()
        pixels = [_pixels(f) for f in figs]
        ticks = sum(len(a.majorTicks) + len(a.minorTicks) for f in figs for ax in f.axes for a in (ax.xaxis, ax.yaxis))
        return pixels, ticks

    (plain, n_plain), (fast, n_fast) = draw(False), draw(True)
    for a, b in zip(plain, fast):
        np.testing.assert_array_equal(a, b)
    assert n_fast < n_plain if x_log else n_fast <= n_plain


@pytest.mark.parametrize("width", [7.5, 3.5])
def test_a_long_title_is_wrapped_inside_the_figure_and_over_its_plot(width):
    """The quickstart's map title (its campaign description, two lines before this test) ran off the
    figure's left edge: wrapped to the figure's width by an estimate, it is centred over the plot,
    which the colour bar makes narrower. Checked on the title as Agg draws it."""
    g, kp, t = _table()
    x, y = Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p")
    title = (
        "γ–k_p sweep of first-order MFC on the simulated DC motor (thesis Sec. 3.5.1, 10 × 10): "
        "RMS of the tracking error e\nδ_t = 35 ms"
    )
    fig = map_figure(Grid.of(t, x, y, ["rms_error"]), "rms_error", title=title, colour_label="RMS", width=width)
    FigureCanvasAgg(fig).draw()
    ax = fig.axes[0]
    drawn = ax.title.get_window_extent()
    plot = ax.get_window_extent()
    assert ax.title.get_text().count("\n") >= 2  # wrapped, the δ_t line kept
    assert plot.x0 - 1 <= drawn.x0 and drawn.x1 <= plot.x1 + 1, (drawn, plot)
    assert drawn.y1 <= fig.bbox.y1  # and not cut at the top


def test_title_lines_fit_their_width_as_agg_draws_them_and_leave_no_word_alone():
    """The valve map's title wrapped greedily left its last word ("e") on a line of its own; the
    lines are as few as fit and of even length. Each line's width as Agg draws it (math type
    included) stays within the width asked for."""
    import matplotlib

    from labrunner.analysis.maps import _wrapped, math_text

    title = "γ–k_p sweep of the MFC of valve V_1P on the simulated valve (paper 1 Sec. 5.1, Fig. 5): RMS of the tracking error e"
    fig = matplotlib.figure.Figure(figsize=(8, 2), dpi=100)
    renderer = FigureCanvasAgg(fig).get_renderer()
    for width in (2.6, 3.4, 4.2, 5.1, 7.0):  # the greedy wrap left "e" alone at 2.6, 3.4 and 5.1 in
        lines = _wrapped(title, width).split("\n")
        assert " ".join(lines) == title
        assert len(lines[-1].split()) > 1, (width, lines)
        for line in lines:
            drawn = fig.text(0, 0, math_text(line), fontsize=matplotlib.rcParams["axes.titlesize"])
            assert drawn.get_window_extent(renderer).width <= width * fig.dpi, (width, line)
            drawn.remove()


def test_a_zipped_gain_that_is_no_function_of_the_swept_one_leaves_the_runs_unjoined():
    """Thesis Fig. 3.11's points on three constant-ratio lines, zipped (γ, k_p): sorted by γ, a line
    through them jumped between the lines (vertical at γ = 447 and 1414, where two lines meet).
    ``follows`` tells such a zip from a sweep along one line; the sweep then draws markers only."""
    from labrunner.analysis.selection import follows

    gamma = [141.42136, 447.21360, 1414.2136, 251.18864, 794.32823, 2511.8864, 447.21360, 1414.2136, 4472.1360]
    k_p = [70.710678, 223.60680, 707.10678, 39.810717, 125.89254, 398.10717, 22.360680, 70.710678, 223.60680]
    three_lines = pd.DataFrame({"controller.gamma": gamma, "controller.k_p": k_p})
    assert not follows(three_lines, "controller.gamma", "controller.k_p")  # two k_p at one γ
    one_line = three_lines.iloc[:3]  # line (A): k_p = γ/2
    assert follows(one_line, "controller.gamma", "controller.k_p")
    assert follows(one_line.assign(**{"controller.k_p": [3.0, 2.0, 1.0]}), "controller.gamma", "controller.k_p")
    zigzag = one_line.assign(**{"controller.k_p": [1.0, 3.0, 2.0]})  # a function, not monotone
    assert not follows(zigzag, "controller.gamma", "controller.k_p")

    t = three_lines.assign(outcome="completed", rms_error=np.arange(1.0, 10.0))
    x = Axis("controller.gamma", np.unique(gamma), True, "γ")
    for joined in (True, False):
        fig = sweep_figure(_points(t), x, [("rms_error", "RMS")], title="s", joined=joined)
        drawn = [line for line in fig.axes[0].get_lines() if len(line.get_xdata()) == len(gamma)]
        assert len(drawn) == joined
        assert len(fig.axes[0].collections[0].get_offsets()) == len(gamma)  # every run's marker either way


@pytest.mark.parametrize("width", [7.5, 3.5])
def test_a_legend_with_long_entries_stays_inside_the_figure(width):
    """A map of thesis Fig. 3.11's points cut its two-column legend at the right edge: a bound
    marked "(outside the map)" is a long entry. The columns are fewer when the widest would not
    fit. Checked on the legend as Agg draws it."""
    g, kp, t = _table()
    x, y = Axis("controller.gamma", g, True, "γ"), Axis("controller.k_p", kp, True, "k_p")
    dense = np.geomspace(0.5, 2e4, 50)
    lines = [
        OverlayLine("stability bound, max k_p (motor model), Eq. (2.46)", dense, 2 * dense, "red", "-", "a"),
        OverlayLine(
            "stability bound, min k_p (motor model), Eq. (2.46) (outside the map)", dense, dense, "red", "--", "b"
        ),
        OverlayLine("stability bound, max k_p (ultra-local model), Eq. (2.41)", dense, 3 * dense, "m", "-", "c"),
        OverlayLine(
            "stability bound, min k_p (ultra-local model), Eq. (2.41) (outside the map)", dense, dense, "m", "--", "d"
        ),
        OverlayLine(
            "stability bound, max k_d (motor model), Eq. (2.52) (outside the map)", dense, dense, "b", "--", "e"
        ),
    ]
    fig = map_figure(
        Grid.of(t, x, y, ["rms_error"]), "rms_error", title="t", colour_label="c", overlays=lines, width=width
    )
    FigureCanvasAgg(fig).draw()
    [legend] = fig.legends
    drawn = legend.get_window_extent()
    assert 0 <= drawn.x0 and drawn.x1 <= fig.bbox.x1 and 0 <= drawn.y0, (drawn, fig.bbox)
    assert (
        drawn.y1 <= fig.axes[0].xaxis.label.get_window_extent().y0
    )  # its rows, wrapped ones too, below the axis label
    short = map_figure(Grid.of(t, x, y, ["rms_error"]), "rms_error", title="t", colour_label="c", width=7.5)
    assert short.legends[0]._ncols == 2  # short entries keep two columns
