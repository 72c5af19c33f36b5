"""A 1-D sweep's figure says what varies (issue 36: subtitled "k_p = 2.5" while a derived k_p = γ/4
ran from 2.5 to 790) and draws its stability limit where the runs' own gains put it."""

from __future__ import annotations

from test_campaign_support import campaign_text, write

from labrunner.analysis import figures
from labrunner.analysis.analyse import analyse
from labrunner.cli import main

GRID = '"controller.gamma" = { log10 = [1.0, 3.5], num = 12 }\n[derived]\n"controller.k_p" = "controller.gamma / 4.0"'


def test_a_sweep_with_a_derived_gain_names_its_range_and_predicts_along_it(project, monkeypatch):
    assert main(["run", str(write(project / "s.toml", campaign_text(name="s", grid=GRID))), "--workers", "1"]) == 0
    seen = []
    monkeypatch.setattr(figures, "map_jobs", lambda *a, _f=figures.map_jobs: seen.append((a, _f(*a))) or seen[-1][1])
    analyse(project / "data" / "s", workers=1, progress=False)
    (frame, _, theories, *_), jobs = seen[0]
    [job] = jobs
    title = job.kwargs["title"]
    kp = frame["controller.k_p"]
    assert f"k_p = {kp.min():.4g} … {kp.max():.4g} along the sweep" in title and "k_p = 2.5," not in title
    # the reference: each run's own prediction (its γ and its k_p), flipping between two runs
    rows = frame.sort_values("controller.gamma")
    theory = figures.common_theory(frame, theories)
    gamma = rows["controller.gamma"].to_numpy()
    checked = 0
    for case in theory.cases():
        known = [
            (g, p[0]) for g, (_, r) in zip(gamma, rows.iterrows()) if (p := theory.predict(case, theories.gains(r)))
        ]
        flips = [(a, b) for (a, s), (b, t) in zip(known, known[1:]) if s != t]
        bounds = [line.x for line in job.kwargs["overlays"] if line.gid == f"bound:{case}:gamma"]
        assert len(bounds) == len(flips) and all(a < x < b for x, (a, b) in zip(sorted(bounds), flips)), case
        checked += len(bounds)
    assert checked >= 1  # the motor's γ sweep crosses a predicted limit
    lo, hi = gamma.min(), gamma.max()
    assert all(lo <= line.x <= hi for line in job.kwargs["overlays"])  # the legend lists only lines in the plot


def _zip_grid(gammas, k_ps) -> str:
    return (
        'zip = [["controller.gamma", "controller.k_p"]]\n'
        f'"controller.gamma" = {{ values = {list(gammas)} }}\n"controller.k_p" = {{ values = {list(k_ps)} }}'
    )


def test_a_zip_whose_gain_is_no_function_of_the_swept_one_draws_runs_unjoined_and_no_bound(project, monkeypatch):
    """Thesis Fig. 3.11's kind of campaign (points on several lines, zipped): sorted by γ a line
    through the runs jumped between the lines, and a bound drawn at an averaged k_p meant nothing."""
    seen = []
    monkeypatch.setattr(figures, "map_jobs", lambda *a, _f=figures.map_jobs: seen.append(_f(*a)) or seen[-1])
    for name, k_ps, joined in (("lines", (10.0, 100.0, 3.0, 30.0), False), ("line", (1.0, 3.0, 3.0, 10.0), True)):
        grid = _zip_grid((100.0, 300.0, 300.0, 1000.0) if not joined else (100.0, 300.0, 310.0, 1000.0), k_ps)
        assert (
            main(["run", str(write(project / f"{name}.toml", campaign_text(name=name, grid=grid))), "--workers", "1"])
            == 0
        )
        analyse(project / "data" / name, workers=1, progress=False)
        [job] = seen[-1]
        assert job.kwargs["joined"] is joined, name
        assert ("scattered over the sweep: runs unjoined, no bound" in job.kwargs["title"]) is not joined
        if not joined:
            assert job.kwargs["overlays"] == []
