"""Campaign files: grid forms and order, stable point ids, safe [derived] expressions, static checks,
and ≥ 20 malformed files that must fail with a one-line error naming the key path, exit 2 and
nothing created (issue 6, "Reliability tests")."""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import given, settings, strategies as st
from test_campaign_support import campaign_text, write

from labrunner.campaign import expressions, grid, spec
from labrunner.cli import main
from labrunner.errors import InvalidParameter

pytestmark = pytest.mark.usefixtures("project")


def load(text: str, name: str = "c.toml"):
    from pathlib import Path

    return spec.load(write(Path("campaigns") / name, text))


# -- grids --------------------------------------------------------------------------------------
def test_log10_axis_is_ten_to_the_exponents_like_thesis_fig_3_10():
    c = load(campaign_text(grid='"controller.gamma" = { log10 = [0.0, 4.0], num = 17 }'))
    gammas = [p["controller.gamma"] for p in c.grid.points()]
    assert len(gammas) == 17
    for i, g in enumerate(gammas):
        assert g == pytest.approx(10 ** (i / 4), rel=1e-12)


def test_linspace_values_and_product_order_first_axis_slowest():
    c = load(
        campaign_text(
            grid='"controller.gamma" = { values = [50, 100] }\n"controller.k_p" = { linspace = [1.0, 3.0], num = 3 }'
        )
    )
    pts = [(p["controller.gamma"], p["controller.k_p"]) for p in c.grid.points()]
    assert pts == [(50, 1.0), (50, 2.0), (50, 3.0), (100, 1.0), (100, 2.0), (100, 3.0)]


def test_zip_pairs_axes_instead_of_a_product():
    g = '"controller.gamma" = { values = [50.0, 100.0, 200.0] }\n"controller.k_p" = { values = [4.0, 2.0, 1.0] }\n'
    g += '"differentiator.omega_c" = { values = [100.0, 200.0] }\nzip = ["controller.gamma", "controller.k_p"]'
    c = load(campaign_text(grid=g))
    pts = [(p["controller.gamma"], p["controller.k_p"], p["differentiator.omega_c"]) for p in c.grid.points()]
    assert c.size == 6
    assert pts[:3] == [(50.0, 4.0, 100.0), (50.0, 4.0, 200.0), (100.0, 2.0, 100.0)]
    assert {g_ * k for g_, k, _ in pts} == {200.0}  # γ/k_p lines of thesis Fig. 3.11 are kept together


def test_unquoted_dotted_keys_are_axes_too():
    c = load(campaign_text(grid="controller.k_p = { values = [1.0, 2.0] }"))
    assert c.grid.keys == ("controller.k_p",)


def test_point_ids_are_stable_and_depend_only_on_identity_and_values():
    a = spec.plan(load(campaign_text()))[0]
    reformatted = "# a comment\n" + campaign_text().replace("k_p = 50.0", "k_p    =   50.0   # base")
    b = spec.plan(load(reformatted, "d.toml"))[0]
    assert [p.id for p in a] == [p.id for p in b]
    assert len({p.id for p in a}) == len(a) == 9
    other = spec.plan(load(campaign_text(name="other"), "e.toml"))[0]
    assert not {p.id for p in a} & {p.id for p in other}
    assert a[0].id == grid.point_id("tiny", a[0].parameters)


def test_plan_checksum_ignores_comments_but_not_settings():
    base = spec.plan(load(campaign_text()))[1]
    assert spec.plan(load("# note\n" + campaign_text(), "b.toml"))[1] == base
    assert spec.plan(load(campaign_text().replace("omega_c = 200.0", "omega_c = 150.0"), "c2.toml"))[1] != base


def test_derived_keys_follow_the_grid_and_use_rig_constants():
    g = '"controller.gamma" = { values = [108.55, 217.1] }'
    extra = (
        '[derived]\n"controller.k_p" = "pi / (2 * 0.035) * controller.gamma / b"\n'
        '"safety.max_du_dt" = "3 * a + controller.k_p / 100"\n'
    )
    c = load(campaign_text(grid=g, extra=extra))
    points, _ = spec.plan(c)
    for p in points:  # k_p,max of thesis (2.41) with ρ = b, δ_t = 35 ms; a, b of rigs/motor.toml
        k_p = math.pi / 0.07 * p.parameters["controller.gamma"] / 108.55
        assert p.parameters["controller.k_p"] == pytest.approx(k_p)
        assert p.parameters["safety.max_du_dt"] == pytest.approx(3 * 39.44 + k_p / 100)  # derived from derived


def test_duration_defaults_to_the_reference_length():
    text = campaign_text(grid='"controller.k_p" = { values = [10.0] }').replace("duration = 2.0\n", "")
    points, _ = spec.plan(load(text))
    assert points[0].batch_key.startswith('["rigs/motor.toml",200.0,1.75,')  # hold + 2·(transition + hold)


def test_batches_separate_controller_kinds_and_fs():
    g = '"campaign.fs" = { values = [100.0, 200.0] }\n"controller.k_p" = { values = [1.0, 2.0] }'
    points, _ = spec.plan(load(campaign_text(grid=g)))
    assert len({p.batch_key for p in points}) == 2


@pytest.mark.parametrize(
    "axis",
    [
        '"campaign.duration" = { values = [1.0, 1.5] }',
        '"differentiator.method" = { values = ["midpoint", "trapezoidal"] }',
    ],
)
def test_batches_separate_durations_and_choices_but_not_gains(axis):
    g = f'{axis}\n"controller.k_p" = {{ values = [1.0, 2.0, 4.0] }}'
    points, _ = spec.plan(load(campaign_text(grid=g)))
    groups: dict[str, set] = {}
    for p in points:
        first = next(iter(p.parameters))
        groups.setdefault(p.batch_key, set()).add(p.parameters[first])
    assert len(groups) == 2 and all(len(v) == 1 for v in groups.values())  # one batch key per value, gains shared


# -- expressions --------------------------------------------------------------------------------
_exprs = st.recursive(
    st.floats(0.1, 100.0).map(lambda x: f"{x!r}") | st.sampled_from(["k", "pi"]),
    lambda inner: st.tuples(inner, st.sampled_from(["+", "-", "*", "/"]), inner).map(
        lambda t: f"({t[0]} {t[1]} {t[2]})"
    ),
    max_leaves=12,
)


@settings(max_examples=150, deadline=None)
@given(_exprs, st.floats(0.5, 50.0))
def test_expressions_agree_with_python_arithmetic(source, k):
    e = expressions.parse("derived.x", source, {"k"})
    try:
        expected = eval(source, {"__builtins__": {}}, {"k": k, "pi": math.pi})  # the reference, in the test only
    except ZeroDivisionError:
        with pytest.raises(InvalidParameter):
            e.evaluate({"k": k})
        return
    if not math.isfinite(expected):
        return
    assert e.evaluate({"k": k}) == pytest.approx(expected, rel=1e-12, abs=1e-300)


@pytest.mark.parametrize(
    "source",
    [
        "__import__('os').system('true')",
        "().__class__.__bases__",
        "lambda: 1",
        "[1, 2]",
        "k if k else 1",
        "k[0]",
        "'text'",
        "True",
        "open('x')",
        "k.__class__",
        "10 ** 10 ** 10",
        "(-8) ** 0.5",
        "1 / 0",
        "k and 1",
    ],
)
def test_expressions_refuse_everything_but_arithmetic(source):
    with pytest.raises(InvalidParameter, match=r"derived\.x"):
        expressions.parse("derived.x", source, {"k"}).evaluate({"k": 2.0})


# -- malformed campaign files -------------------------------------------------------------------
GOOD = campaign_text()
MALFORMED = {
    "unknown-section": (GOOD + "\n[controler]\nk_p = 1\n", "controler"),
    "unknown-campaign-key": (GOOD.replace("seed = 3", "seed = 3\nnmae = 'x'"), "campaign.nmae"),
    "missing-name": (GOOD.replace('name = "tiny"\n', ""), "campaign.name"),
    "bad-name": (GOOD.replace('name = "tiny"', 'name = "Tiny Campaign"'), "campaign.name"),
    "fs-wrong-type": (GOOD.replace("fs = 200.0", 'fs = "200"'), "campaign.fs"),
    "negative-duration": (GOOD.replace("duration = 2.0", "duration = -1.0"), "campaign.duration"),
    "float-seed": (GOOD.replace("seed = 3", "seed = 1.5"), "campaign.seed"),
    "unknown-rig": (GOOD.replace('rig = "rigs/motor.toml"', 'rig = "nosuchrig"'), "campaign.rig"),
    "rig-outside-project": (GOOD.replace('rig = "rigs/motor.toml"', 'rig = "../../../etc/motor.toml"'), "campaign.rig"),
    "rig-absolute-outside": (GOOD.replace('rig = "rigs/motor.toml"', 'rig = "/etc/passwd"'), "campaign.rig"),
    "empty-grid": (campaign_text(grid=""), "grid"),
    "empty-values": (campaign_text(grid='"controller.k_p" = { values = [] }'), "controller.k_p"),
    "zero-num": (campaign_text(grid='"controller.k_p" = { log10 = [0, 2], num = 0 }'), "controller.k_p"),
    "two-forms": (
        campaign_text(grid='"controller.k_p" = { values = [1], linspace = [0, 1], num = 2 }'),
        "controller.k_p",
    ),
    "unknown-axis-key": (campaign_text(grid='"controller.k_p" = { values = [1], step = 2 }'), 'controller.k_p".step'),
    "axis-unknown-section": (campaign_text(grid='"controler.k_p" = { values = [1] }'), "controler.k_p"),
    "axis-campaign-name": (campaign_text(grid='"campaign.name" = { values = ["a"] }'), "campaign.name"),
    "zip-unequal": (
        campaign_text(
            grid='"controller.k_p" = { values = [1, 2] }\n"controller.gamma" = { values = [1] }\nzip = ["controller.k_p", "controller.gamma"]'
        ),
        "grid.zip",
    ),
    "zip-unknown-axis": (
        campaign_text(grid='"controller.k_p" = { values = [1, 2] }\nzip = ["controller.k_p", "controller.x"]'),
        "grid.zip",
    ),
    "enormous-grid": (
        campaign_text(
            grid='"controller.k_p" = { log10 = [0, 2], num = 1000 }\n"controller.gamma" = { log10 = [0, 2], num = 1001 }'
        ),
        "grid",
    ),
    "derived-call": (
        campaign_text(grid='"controller.gamma" = { values = [1.0] }')
        + '\n[derived]\n"controller.k_p" = "__import__(\'os\').getcwd()"\n',
        'derived."controller.k_p": call of',
    ),
    "derived-unknown-name": (
        campaign_text(grid='"controller.gamma" = { values = [1.0] }')
        + '\n[derived]\n"controller.k_p" = "2 * controller.kp"\n',
        'derived."controller.k_p"',
    ),
    "derived-syntax": (
        campaign_text(grid='"controller.gamma" = { values = [1.0] }') + '\n[derived]\n"controller.k_p" = "2 *"\n',
        "derived",
    ),
    "derived-division-by-zero": (
        campaign_text(grid='"controller.gamma" = { values = [1.0] }')
        + '\n[derived]\n"controller.k_p" = "1 / (controller.gamma - 1)"\n',
        'derived."controller.k_p"',
    ),
    "alpha-too-small-for-order": (
        campaign_text(grid='"controller.k_p" = { values = [100.0] }')
        .replace('kind = "mfc1"\noutput = "velocity"', 'kind = "mfc2"\noutput = "angle"\nk_d = 50.0')
        .replace("alpha = 9\nbeta = 9", "alpha = 1\nbeta = 1"),
        "differentiator.",
    ),
    "omega-c-above-nyquist": (
        campaign_text(grid='"differentiator.omega_c" = { values = [100.0, 2000.0] }'),
        "differentiator.omega_c",
    ),
    "fs-outside-rig-range": (GOOD.replace("fs = 200.0", "fs = 1.0e6"), "campaign.fs"),
    "negative-gain": (campaign_text(grid='"controller.k_p" = { linspace = [-1.0, 1.0], num = 3 }'), "controller.k_p"),
    "nan-gain": (campaign_text(grid='"controller.k_p" = { values = [nan] }'), "controller.k_p"),
    "unknown-controller-key": (GOOD.replace("k_p = 50.0", "k_p = 50.0\nkp = 5.0"), "controller.kp"),
    "unknown-rig-parameter": (GOOD + "\n[rig_parameters]\nmass = 2.0\n", "rig_parameters.mass"),
    "unknown-safety-key": (GOOD.replace("max_du_dt = 120.0", "max_du_dt = 120.0\nmax_dudt = 1.0"), "safety.max_dudt"),
    "derived-shadows-axis": (GOOD + '\n[derived]\n"controller.k_p" = "2.0"\n', 'derived."controller.k_p"'),
    "not-toml": ("[campaign\nname = 'x'\n", "c.toml"),
    "gain-string-in-grid": (campaign_text(grid='"controller.k_p" = { values = ["fast"] }'), "controller.k_p"),
    "gain-boolean": (
        campaign_text(grid='"controller.gamma" = { values = [1.0] }').replace("k_p = 50.0", "k_p = true"),
        "controller.k_p",
    ),
    "num-not-integer": (
        campaign_text(grid='"controller.k_p" = { linspace = [1, 2], num = 2.5 }'),
        'controller.k_p".num',
    ),
    "levels-not-a-list": (GOOD.replace("levels = [0.0, 20.0, 0.0]", 'levels = "high"'), "reference.levels"),
    "unknown-controller-kind": (GOOD.replace('kind = "mfc1"', 'kind = "pid"'), "controller.kind"),
    "rig-not-a-toml-file": (GOOD.replace('rig = "rigs/motor.toml"', 'rig = "pyproject.tom"'), "campaign.rig"),
    "duplicate-grid-values": (campaign_text(grid='"controller.k_p" = { values = [1.0, 1.0] }'), "grid"),
    "input-limit-beyond-rig": (GOOD.replace("k_p = 50.0", "k_p = 50.0\nu_max = 100.0"), "controller.u_max"),
    "derived-above-nyquist": (
        campaign_text(grid='"controller.k_p" = { values = [1.0] }')
        + '\n[derived]\n"differentiator.omega_c" = "1e3 * pi"\n',
        "differentiator.omega_c",
    ),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_campaign_fails_with_key_path_exit_2_and_creates_nothing(case, project, capsys):
    text, key = MALFORMED[case]
    path = write(project / "campaigns" / "c.toml", text)
    before = sorted(p.relative_to(project) for p in project.rglob("*"))
    code = main(["run", str(path)])  # into the default data/<name>/
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("labrunner run: error: "), err
    assert key in err, err
    assert sorted(p.relative_to(project) for p in project.rglob("*")) == before  # no directory, no ledger
    assert not (project / "data").exists()


def test_enormous_grid_message_names_the_limit(project, capsys):
    path = write(project / "c.toml", MALFORMED["enormous-grid"][0])
    assert main(["run", str(path), "--dry-run"]) == 2
    assert re.search(r"1,001,000 points, more than the limit of 1,000,000", capsys.readouterr().err)


def test_dry_run_prints_points_batches_estimate_and_creates_nothing(project, capsys):
    path = write(project / "c.toml", GOOD)
    assert main(["run", str(path), "--dry-run", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    # 9 points on 2 workers, far below the cost model's and the memory budget's batch sizes:
    # one batch per worker → batches of ⌈9/2⌉ = 5
    assert out.startswith("campaign tiny: 9 points on rig 'rigs/motor.toml', 2 batches\n"), out
    assert "9 points × 2 s at 200 Hz (mfc1): 2 batches of ≤ 5" in out
    estimate = re.search(
        r"estimated time ≈ (\d+) s on 2 worker\(s\) at this machine.s present load \(timed now; 18 s of simulated time\)",
        out,
    )
    assert estimate and 0 <= int(estimate[1]) < 60, out
    assert not (project / "data").exists()


def test_numbers_a_batch_must_share_are_discovered_and_split_batches():
    text = """
[campaign]
name = "plate-notch"
rig = "plate-sim"
duration = 0.01
[controller]
kind = "plate-mfc"
gamma = 1.0
k_p = 5000.0
k_d = 195.0
[differentiator]
alpha = 4
beta = 4
omega_c = 840.0
[reference]
kind = "lift"
[grid]
"controller.notch_omega" = { values = [800.0, 942.0] }
"controller.k_p" = { values = [4000.0, 5000.0] }
"""
    points, _ = spec.plan(load(text))
    keys = {
        p.batch_key: {q.parameters["controller.notch_omega"] for q in points if q.batch_key == p.batch_key}
        for p in points
    }
    assert len(keys) == 2 and all(len(v) == 1 for v in keys.values())  # the plate MFC needs one notch per batch


# -- [metrics] windows ----------------------------------------------------------------------------
def test_metrics_windows_reach_every_point_and_leave_other_campaigns_unchanged():
    with_windows = load(campaign_text(extra="[metrics]\nhold = [0.5, 1.0]\nfault = [1.0, 2.0]\n"), "w.toml")
    configs = [config for _, config in with_windows.points()]
    assert all(c["metrics"] == {"hold": [0.5, 1.0], "fault": [1.0, 2.0]} for c in configs)
    plain = load(campaign_text(), "p.toml")
    assert all("metrics" not in c for _, c in plain.points())  # plan checksums of older campaigns stay


@pytest.mark.parametrize(
    "body, field",
    [
        ("fault = [2.0, 1.0]", "metrics.fault"),
        ("fault = 1.0", "metrics.fault"),
        ("'a b' = [0.0, 1.0]", "metrics.a b"),
    ],
)
def test_bad_metrics_windows_name_the_key(body, field):
    with pytest.raises(InvalidParameter) as exc:
        load(campaign_text(extra=f"[metrics]\n{body}\n"), "bad.toml")
    assert exc.value.field == field


@settings(max_examples=200, deadline=None)
@given(n=st.integers(1, 30_000), slots=st.integers(1, 32), samples=st.integers(1, 200_000))
def test_batches_are_as_large_as_cost_and_memory_allow_and_keep_every_worker_busy(n, slots, samples):
    """Every point in exactly one batch; sizes differ by one at most; none above the memory
    budget; the largest batch is that of ⌈n / (slots·m)⌉·slots equal batches, m the smallest of
    the cost model's and the memory budget's sizes (so no worker idles while another runs a batch
    of its own at the end); batch j of c holds the points j, j + c, … (each samples the whole grid)."""
    from labrunner.campaign import scheduler

    rows = [{"batch_key": f'["rig", 200.0, {samples / 200.0}, [], 0]', "seq": i} for i in range(n)]
    batches = scheduler.make_batches(rows, slots)
    assert sorted(r["seq"] for _, b in batches for r in b) == list(range(n))
    assert all([r["seq"] for r in b] == list(range(j, n, len(batches))) for j, (_, b) in enumerate(batches))
    sizes = [len(b) for _, b in batches]
    by_memory = max(1, scheduler.BATCH_MEMORY_BYTES // (samples * scheduler._BYTES_PER_SAMPLE))
    m = min(by_memory, math.ceil(9 * scheduler.TICK_OVERHEAD_S / scheduler.RUN_TICK_S))
    assert max(sizes) - min(sizes) <= 1 and max(sizes) <= by_memory
    assert max(sizes) == math.ceil(n / (slots * math.ceil(n / (slots * m))))
    requested = scheduler.make_batches(rows, slots, requested=7)
    assert [r["seq"] for _, b in requested for r in b] == list(range(n))  # in grid order
    assert len(requested[0][1]) == min(7, n)
