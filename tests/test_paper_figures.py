"""Issue 34 part 3: figures for papers. ``analyse --format png,pdf,svg --size column|page
--no-title`` and ``plot --size`` write vector figures with their fonts embedded, at a paper's
column or page width, with symbols in math type and legends that say what a line is; the same
figures come from Python (``CampaignResults.plot_map``, ``RunResults.plot``) as matplotlib Figures.
The PDFs are checked by reading the files themselves (their fonts' dictionaries and page boxes),
and with poppler's ``pdffonts`` where it is installed."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import zlib
from pathlib import Path

import pytest
from matplotlib.figure import Figure
from test_campaign_support import MOTOR_RIG, campaign_text, cli, write

import labrunner

GRID = '"controller.gamma" = { log10 = [0.0, 4.0], num = 4 }\n"controller.k_p" = { log10 = [-1.0, 3.0], num = 4 }'
RIG_GRID = '"controller.k_p" = { log10 = [0.0, 2.0], num = 3 }\n"rig_parameters.a" = { values = [30.0, 40.0] }'
DESCRIPTION = "DC motor twin, first-order MFC"


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A γ–k_p campaign with a description, and a k_p × rig-parameter one, run on the motor twin."""
    root = tmp_path_factory.mktemp("paper")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    write(root / "rigs" / "motor.toml", MOTOR_RIG)
    text = campaign_text("gains", duration=1.0, grid=GRID).replace("test campaign", DESCRIPTION)
    for name, body in (("gains", text), ("rig", campaign_text("rig", duration=1.0, grid=RIG_GRID))):
        path = write(root / "campaigns" / f"{name}.toml", body)
        done = cli("run", str(path), "--out", str(root / name), "--workers", "1", cwd=root)
        assert done.returncode == 0, done.stderr
    return root


def _analyse(project: Path, name: str, *options: str) -> Path:
    out = project / name / "paper"
    shutil.rmtree(out, ignore_errors=True)
    done = cli("analyse", str(project / name), "--out", str(out), "--workers", "1", *options, cwd=project)
    assert done.returncode == 0, done.stderr
    return out


def _objects(pdf: bytes) -> str:
    """The PDF's text with every Flate stream inflated (matplotlib compresses the page, not the font dictionaries)."""
    parts = [pdf.decode("latin-1")]
    for match in re.finditer(rb"stream\r?\n(.*?)endstream", pdf, re.S):
        try:
            parts.append(zlib.decompress(match.group(1)).decode("latin-1"))
        except zlib.error:
            pass
    return "\n".join(parts)


def _page_size(pdf: bytes) -> tuple[float, float]:
    box = re.search(rb"/MediaBox \[\s*0 0 ([\d.]+) ([\d.]+)\s*\]", pdf)
    assert box, "no MediaBox"
    return float(box.group(1)), float(box.group(2))


def _fonts_embedded(path: Path) -> None:
    """Every font of the PDF is a TrueType font whose program is in the file (no Type 3 glyph procedures)."""
    text = _objects(path.read_bytes())
    subtypes = re.findall(r"/Subtype\s*/(Type3|TrueType|Type1|CIDFontType2|Type0)", text)
    assert subtypes and "Type3" not in subtypes and "Type1" not in subtypes, subtypes
    assert "/FontFile2" in text  # the TrueType program embedded
    if shutil.which("pdffonts") or os.environ.get("LABRUNNER_CI") == "1":
        rows = subprocess.run(["pdffonts", str(path)], capture_output=True, text=True, check=True).stdout.splitlines()[
            2:
        ]
        assert rows and all(" yes " in row and "TrueType" in row for row in rows), rows


def test_formats_embedded_fonts_and_column_width(project):
    out = _analyse(project, "gains", "--format", "png,pdf,svg", "--size", "column", "--no-title")
    for stem in ("map_rms_error", "map_input_energy"):
        for suffix in (".png", ".pdf", ".svg"):
            assert (out / f"{stem}{suffix}").is_file(), stem + suffix
        pdf = out / f"{stem}.pdf"
        _fonts_embedded(pdf)
        width, height = _page_size(pdf.read_bytes())
        assert width == pytest.approx(3.5 * 72) and height > 0.62 * width
        svg = (out / f"{stem}.svg").read_text()
        assert "<text" not in svg and "<path" in svg  # text drawn as paths: no font needed to show it
    plots = list((out / "plots").glob("*.pdf"))
    assert plots and {p.with_suffix(".png").is_file() for p in plots} == {True}
    for plot in plots:
        _fonts_embedded(plot)
        assert _page_size(plot.read_bytes())[0] == pytest.approx(3.5 * 72)
    assert "<img" in (out / "index.html").read_text()  # the report still shows the PNGs


def test_page_width_and_the_dpi_of_the_png(project):
    from matplotlib.image import imread

    out = _analyse(project, "gains", "--format", "pdf", "--size", "page", "--dpi", "200")
    assert _page_size((out / "map_rms_error.pdf").read_bytes())[0] == pytest.approx(7.16 * 72)
    assert imread(out / "map_rms_error.png").shape[1] == round(7.16 * 200)
    assert not (out / "map_rms_error.svg").exists()


@pytest.mark.parametrize(
    ("option", "value", "field"),
    [("--format", "png,eps", "--format"), ("--dpi", "5", "dpi"), ("--dpi", "nan", "--dpi")],
)
def test_bad_figure_options_are_refused_in_one_line(project, option, value, field):
    out = project / "gains" / "refused"
    done = cli("analyse", str(project / "gains"), "--out", str(out), option, value, cwd=project)
    assert done.returncode != 0 and field in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not out.exists()


def test_map_from_python_is_the_analysis_figure(project):
    campaign = labrunner.open_campaign(project / "gains")
    fig = campaign.plot_map("rms_error", size="column")
    assert isinstance(fig, Figure)
    assert tuple(fig.get_size_inches().round(3))[0] == 3.5
    ax = fig.axes[0]
    assert ax.get_xlabel().startswith(r"input gain $\gamma$") and r"$k_\mathrm{p}$" in ax.get_ylabel()
    assert DESCRIPTION in ax.get_title()  # the description, not the file's name
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert r"stability bound, max $k_\mathrm{p}$ (motor model), Eq. (2.46)" in legend
    assert any(re.fullmatch(r"nominal input gain \$\\rho\$ = 108\.55", t) for t in legend), legend
    untitled = campaign.plot_map("input_energy", title=False)
    assert untitled.axes[0].get_title() == "" and untitled.get_size_inches()[0] == 7.5
    ax.set_title("restyled")  # an ordinary Figure: the user's to change and save
    with pytest.raises(labrunner.errors.InvalidParameter, match="metric"):
        campaign.plot_map("no_such_metric")


def test_rig_parameter_axis_has_its_unit(project):
    fig = labrunner.open_campaign(project / "rig").plot_map("rms_error")
    labels = {fig.axes[0].get_xlabel(), fig.axes[0].get_ylabel()}
    assert "a [1/s]" in labels  # the dcmotor schema's unit of its parameter a


def test_run_plot_from_python_and_from_the_cli(project, tmp_path):
    campaign = labrunner.open_campaign(project / "gains")
    row = campaign.select(outcome="completed").iloc[0]
    fig = campaign.run(row["id"]).plot(size="column")
    assert isinstance(fig, Figure) and fig.get_size_inches()[0] == pytest.approx(3.5)
    assert fig.axes[-1].get_xlabel() == "t [s]"
    pdf = tmp_path / "run.pdf"
    done = cli("plot", row["log_path"], "-o", str(pdf), "--size", "page", cwd=project)
    assert done.returncode == 0, done.stderr
    _fonts_embedded(pdf)
    assert _page_size(pdf.read_bytes())[0] == pytest.approx(7.16 * 72)
