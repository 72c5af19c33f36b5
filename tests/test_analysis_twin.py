"""End to end on the simulated DC motor: a small γ–k_p campaign of first-order MFC (thesis Fig. 3.10),
run by `labrunner run`, analysed by `labrunner analyse --json`: overlays (2.41)/(2.46) at δ_t = 35 ms,
the nominal-gain line, outcomes vs. theory."""

import json
from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import imread
from test_campaign_support import campaign_text

from labrunner.analysis.context import Theories
from labrunner.analysis.figures import axis_of, map_overlays
from labrunner.analysis.selection import load_campaign, varying_axes
from labrunner.campaign.ledger import Ledger
from labrunner.cli import main

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = campaign_text(  # the rig file's safety routine; runs as long as the reference
    "analysis-twin",
    rig="dcmotor-sim",
    duration=None,
    seed=0,
    hold=0.5,
    grid='"controller.gamma" = { log10 = [1.0, 4.0], num = 4 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 5 }',
)


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("twin")
    file, out = tmp / "analysis-twin.toml", tmp / "campaign"
    file.write_text(CAMPAIGN, encoding="utf-8")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        assert main(["run", str(file), "--out", str(out), "--workers", "1"]) == 0
        return out, _json(["analyse", str(out), "--json", "--workers", "1"])


def _json(argv):
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(argv) == 0
    return json.loads(buf.getvalue())


def test_summary_counts_and_agreement(analysed):
    out, summary = analysed
    assert summary["runs"] == summary["points"] == 20
    o = summary["outcomes"]
    assert o["completed"] + o["no-motion"] + o["aborted"] + o["failed"] == 20
    assert o["aborted"] > 0 and o["completed"] > 0
    agree = summary["agreement"]
    assert agree["case"] == "mfc1-motor" and agree["margin"] == 0.1
    assert agree["n_compared"] + agree["n_excluded"] == 20 - o["failed"]
    assert agree["share"] > 0.8  # the twin follows (2.46) away from its bounds
    best = summary["best"]
    assert set(best["params"]) == {"controller.gamma", "controller.k_p"} and best["rms"] > 0
    for path in summary["maps"]:
        height, width = imread(path).shape[:2]  # 7.5 in at 110 dpi; the plot 0.62 of that, the legend below
        assert width == 825 and 0.62 * 825 < height < 825
    assert len(summary["run_plots"]) == 3 and not summary["problems"]


def test_map_overlays_of_the_campaign(analysed):
    out, _ = analysed
    import pandas as pd

    table = pd.read_parquet(out / "report" / "metrics.parquet")
    with Ledger.open_readonly(out) as ledger:
        campaign, note = load_campaign(ledger.meta(), out)
    assert campaign is not None, note
    assert varying_axes(table, campaign) == ["controller.gamma", "controller.k_p"]
    x, y = axis_of(table, "controller.gamma", {}), axis_of(table, "controller.k_p", {})
    assert x.log and y.log
    lines, text = map_overlays(table, x, y, Theories(campaign))
    assert text == "δ_t = 35 ms"  # α = β = 9, ω_c = 200 rad/s, f_s = 200 Hz (thesis Sec. 3.4)
    gids = {line.gid: line for line in lines}
    assert set(gids) == {
        "bound:mfc1-ultralocal:k_p_max",
        "bound:mfc1-motor:k_p_max",
        "bound:mfc1-motor:k_p_min",
        "nominal-gain",
    }
    assert gids["nominal-gain"].x == pytest.approx(108.55)
    hi = gids["bound:mfc1-ultralocal:k_p_max"]
    np.testing.assert_allclose(hi.y, np.pi / 2 * hi.x / (108.55 * 0.035), rtol=1e-9)
    html = (out / "report" / "index.html").read_text(encoding="utf-8")
    assert "mfc1-motor" in html and "analysis-twin" in html and "δ_t" in html
