"""The campaign pack (campaigns/thesis, valve-paper, plate-paper and its fault rigs): every file is
headed by the figure it reproduces and passes the static checks, quick variants are smaller grids of
the same campaigns, the fault rigs are the plate twin plus their fault, and a bad fault rig file is
reported with its file and key."""

import re
import tomllib
from pathlib import Path

import pytest

from labrunner.campaign import spec
from labrunner.cli import main
from labrunner.reproduce.items import ITEMS, select
from labrunner.reproduce.run import variant_text

ROOT = Path(__file__).resolve().parents[1]
PACK = sorted({f for item in ITEMS for f in item.files})
HEAD = re.compile(r"\A# .*\n# .*|\A# .*")  # the first two comment lines ...
FIGURE = re.compile(r"(Figs?\.|Table|Sec\.) \d")  # ... name the figure, table or section reproduced


@pytest.mark.parametrize("file", PACK, ids=[Path(f).stem for f in PACK])
def test_every_pack_file_names_its_figure_and_passes_the_static_checks(file):
    path = ROOT / file
    head = HEAD.match(path.read_text(encoding="utf-8"))
    assert head and FIGURE.search(head.group(0)), f"{file} is not headed by the figure it reproduces"
    if "/thesis/" in file or "-paper/" in file:
        assert re.match(r"# (Thesis|Paper [12]) (Figs?\.|Table|Sec\.) ", head.group(0)), file
    points, _ = spec.plan(spec.load(path))
    assert points


@pytest.mark.parametrize("item", [i for i in ITEMS if i.quick_grids], ids=lambda i: i.id)
def test_quick_variants_are_smaller_grids_of_the_same_campaign(item):
    for file, grid in item.quick_grids.items():
        text = (ROOT / file).read_text(encoding="utf-8")
        full, quick = (
            spec.from_text(text, source_path=ROOT / file),
            spec.from_text(variant_text(text, grid), source_path=ROOT / file),
        )
        assert quick.name == full.name + "-quick"
        assert quick.size < full.size
        assert quick.base == full.base and quick.rig == full.rig  # only the grid differs
        spec.plan(quick)


def test_variant_text_replaces_only_the_grid_section():
    text = '[campaign]\nname = "x"\n\n[grid]\n"a.b" = { values = [1, 2] }\n\n[derived]\n"c.d" = "a.b"\n'
    out = variant_text(text, '"a.b" = { values = [1] }')
    assert out == '[campaign]\nname = "x-quick"\n\n[grid]\n"a.b" = { values = [1] }\n\n[derived]\n"c.d" = "a.b"\n'


@pytest.mark.parametrize("fault", ["actuator-offset", "actuator-gain", "sensor"])
def test_fault_rigs_are_the_plate_twin_plus_their_fault(fault):
    """Paper 2 Sec. 4.4: K_i = 400 mA on i_1, (1 + 0.4) i_1, K_y = 0.2 mm on y_1, here from 2.5 s on."""
    base = tomllib.loads((ROOT / "rigs" / "plate-sim.toml").read_text(encoding="utf-8"))
    rig = tomllib.loads((ROOT / "rigs" / f"plate-fault-{fault}.toml").read_text(encoding="utf-8"))
    faults = rig.pop("faults")
    assert rig["rig"].pop("description") != base["rig"].pop("description")
    assert rig == base
    expected = {
        "actuator-offset": ("actuator_offset", [0.4, 0.0, 0.0, 0.0]),
        "actuator-gain": ("actuator_gain", [0.4, 0.0, 0.0, 0.0]),
        "sensor": ("sensor_step", [2e-4, 0.0, 0.0, 0.0]),
    }[fault]
    assert faults == {"t_start": 2.5, expected[0]: expected[1]}


def test_wrong_length_sensor_step_names_the_file_and_key(tmp_path, monkeypatch, capsys):
    (tmp_path / "rigs").mkdir()
    (tmp_path / "pyproject.toml").write_text("")
    text = (ROOT / "rigs" / "plate-fault-sensor.toml").read_text(encoding="utf-8")
    (tmp_path / "rigs" / "plate-bad.toml").write_text(text.replace("[2.0e-4, 0.0, 0.0, 0.0]", "[2.0e-4, 0.0, 0.0]"))
    campaign = (ROOT / "campaigns/plate-paper/table3-sensor-mbc.toml").read_text(encoding="utf-8")
    (tmp_path / "c.toml").write_text(campaign.replace('rig = "plate-fault-sensor"', 'rig = "plate-bad"'))
    monkeypatch.chdir(tmp_path)
    assert main(["run", "c.toml", "--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "plate-bad.toml" in err[0] and "faults.sensor_step" in err[0] and "got 3" in err[0]


def test_unknown_figure_is_refused_before_anything_runs(tmp_path, capsys):
    assert main(["reproduce", "--only", "3.99", "--out", str(tmp_path / "r")]) == 2
    assert "--only" in capsys.readouterr().err and not (tmp_path / "r").exists()
    assert [i.id for i in select(("3.8", "3.7", "3.8"))] == ["3.8", "3.7"]
