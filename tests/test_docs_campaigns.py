"""docs/campaigns.md's reference-kind table against the code (issue 36: the page listed a `sine`
reference that mfc1 refuses and none of the keys of `steps` and `sine`)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from labrunner.campaign import spec
from labrunner.control.factory import REFERENCE_KEYS
from labrunner.errors import InvalidParameter

DOC = Path(__file__).resolve().parents[1] / "docs" / "campaigns.md"


def _table() -> dict[str, tuple[set[str], str]]:
    """kind → (keys named in its row, the 'taken by' cell), from the reference-kind table."""
    text = DOC.read_text(encoding="utf-8")
    section = text[text.index("### Reference kinds") : text.index("### Grid axes")]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 3 and re.fullmatch(r"`\w+`", cells[0]):
            rows[cells[0].strip("`")] = (set(re.findall(r"`(\w+)`", cells[1])), cells[2])
    return rows


def test_the_table_lists_every_reference_kind_with_its_keys():
    rows = _table()
    assert set(rows) == set(REFERENCE_KEYS)
    for kind, keys in REFERENCE_KEYS.items():
        assert rows[kind][0] == set(keys), kind


def _campaign(controller: str, reference: str) -> str:
    return f"""
[campaign]
name = "ref"
rig = "dcmotor-sim"
fs = 100.0
duration = 2.0

[controller]
{controller}

[reference]
{reference}

[safety]
max_du_dt = 1.0e6
"""


MFC1 = 'kind = "mfc1"\noutput = "velocity"\ngamma = 108.55\nk_p = 50.0\n[differentiator]\nalpha = 9\nbeta = 9\nN = 0\nomega_c = 200.0\nmethod = "midpoint"'
SINE = 'kind = "sine"\namplitude = 6.0\nfrequency = 1.0\nduration = 2.0'
STEPS = 'kind = "steps"\nlevels = [0.0, 6.0]\ndurations = [0.5, 1.5]'


@pytest.mark.parametrize("reference", [SINE, STEPS])
def test_open_loop_takes_steps_and_sine_and_mfc1_refuses_them_as_the_table_says(tmp_path, reference):
    kind = reference.split('"')[1]
    assert "`open-loop`" in _table()[kind][1] and "mfc1" not in _table()[kind][1]
    path = tmp_path / "ref.toml"
    path.write_text(_campaign('kind = "open-loop"', reference))
    points, _ = spec.plan(spec.load(path))
    assert len(points) == 1
    path.write_text(_campaign(MFC1, reference))
    with pytest.raises(InvalidParameter, match=f"reference.kind: must be one of 'setpoints', got '{kind}'"):
        spec.plan(spec.load(path))
