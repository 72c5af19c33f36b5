"""Per-run choices (``factory.PER_RUN_CHOICES``: the plate MFC's input law) do not split batches: they are
a batch key's sixth element, keys that differ only there share batches where that makes fewer of them,
a mixed batch runs each run as a batch of its own law would, and ledgers planned with the old
five-element keys still resume."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from labrunner import engine
from labrunner.campaign import checks, runner, spec
from labrunner.campaign.dry_run import grid_text
from labrunner.campaign.ledger import Ledger
from labrunner.campaign.scheduler import Outcome, family, make_batches, merges, planned_batches
from labrunner.rigs import registry

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "campaigns" / "plate-paper"
LAWS = {"v": 1.0, "force": 1.0, "u": 1.6e-5, "current": 0.04}  # paper 2 Sec. 4.1's input gains


def _plate_campaign(directory: Path, name: str = "laws", duration: float = 0.05) -> Path:
    """The four MFC input laws of Table 3 on the plate twin, ``duration`` s each."""
    (directory / "rigs").mkdir(exist_ok=True)
    shutil.copy(ROOT / "rigs" / "plate-sim.toml", directory / "rigs")
    text = (PAPER / "table3-horizontal-mfc.toml").read_text(encoding="utf-8")
    text = text.replace('name = "plate-paper-table3-horizontal-mfc"', f'name = "{name}"\nduration = {duration}')
    text = text.split("[metrics]")[0] + "[grid]" + text.split("[grid]")[1]  # no window past a short run
    path = directory / f"{name}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _batches(name: str, slots: int) -> list[tuple[str, list[str]]]:
    """The shipped campaign ``name``'s batches on ``slots`` workers, as the inputs of their runs."""
    points, _ = spec.plan(spec.load(PAPER / f"{name}.toml"))
    rows = [{"batch_key": p.batch_key, "input": p.parameters["controller.input"]} for p in points]
    return [(key, [r["input"] for r in members]) for key, members in make_batches(rows, slots)]


@pytest.mark.parametrize("slots", [1, 2])
def test_table3_laws_share_batches(slots):
    batches = _batches("table3-tilt-mfc", slots)
    assert sorted(x for _, inputs in batches for x in inputs) == sorted(LAWS)
    assert [len(inputs) for _, inputs in batches] == [4 // slots] * slots  # 1 of 4, or 2 of 2 (not 4 of 1)
    for key, _ in batches:  # a mixed batch carries what its runs share: no input
        assert len(json.loads(key)) == 5 and "controller.input" not in dict(json.loads(key)[3])


def test_fig08_laws_that_fill_the_workers_stay_apart():
    """Four laws × 8 gains on 2 workers: 8 batches of 4 either way, so each batch keeps one law."""
    batches = _batches("fig08-input-gains", 2)
    assert [len(inputs) for _, inputs in batches] == [4] * 8
    assert all(len(set(inputs)) == 1 for _, inputs in batches)
    assert all(json.loads(key)[5] == [["controller.input", inputs[0]]] for key, inputs in batches)


def test_the_merge_rule():
    key = json.dumps(["plate-sim", 32000.0, 3.9, [], []])
    assert merges(key, [1, 1, 1, 1], slots=2) and merges(key, [1, 1, 1, 1], slots=1)
    assert not merges(key, [8, 8, 8, 8], slots=2)  # Fig. 8: the memory budget holds 8 runs of 3.9 s a batch
    assert merges(key, [3, 1], slots=1)  # 1 batch of 4 rather than 2
    assert not merges(key, [1, 1, 1, 1], slots=2, requested=1)  # a real rig's one run at a time


def test_keys_keep_per_run_choices_apart():
    found = [("controller.input", "u"), ("controller.kind", "plate-mfc"), ("reference.kind", "tilt")]
    key = json.loads(checks.batch_key_of("plate-sim", 32000.0, 3.5, found, []))
    assert key == ["plate-sim", 32000.0, 3.5, [["controller.kind", "plate-mfc"], ["reference.kind", "tilt"]], [],
                   [["controller.input", "u"]]]  # fmt: skip
    other = [("controller.input", "u"), ("controller.kind", "plate-mbc")]  # another kind's input is no choice of it
    assert len(json.loads(checks.batch_key_of("plate-sim", 32000.0, 3.5, other, []))) == 5
    assert family(json.dumps(key)) == json.dumps(key[:5], separators=(",", ":"), sort_keys=True)


def test_a_batch_number_the_laws_must_share_still_splits_them(tmp_path):
    """The static checks build a chunk's laws together, so a number a batch must share (the weights of
    eq. (18)) splits the laws' keys as it would split one law's, and no mixed batch fails to build."""
    path = _plate_campaign(tmp_path)
    text = path.read_text(encoding="utf-8").replace(
        '"controller.gamma" = { values = [1.0, 1.0, 1.6e-5, 0.04] }',
        '"controller.gamma" = { values = [1.0, 1.6e-5, 0.04] }\n'
        '"controller.weights" = { values = [[0.2, 0.4, 0.4], [0.0, 0.5, 0.5], [0.0, 0.5, 0.5]] }',
    )
    path.write_text(text.replace('["v", "force", "u", "current"]', '["force", "u", "current"]').replace(
        '["controller.input", "controller.gamma"]', '["controller.input", "controller.gamma", "controller.weights"]'
    ), encoding="utf-8")  # fmt: skip
    points, _ = spec.plan(spec.load(path))
    batches = make_batches([{"batch_key": p.batch_key, "p": p.parameters} for p in points], 1)
    assert sorted(len(b) for _, b in batches) == [1, 2]  # force alone; u and current together


def test_a_mixed_batch_runs_each_law_as_its_own_batch_would(tmp_path):
    """Through the engine (rig, safety, metrics): every run of a batch of the four laws equals the same
    run in a batch of its law alone of the same size."""
    campaign = spec.load(_plate_campaign(tmp_path, duration=0.2))
    points, _ = spec.plan(campaign)
    configs = []
    for p in points:
        config = campaign.resolve(p.parameters)
        config["campaign"]["duration"] = json.loads(p.batch_key)[2]
        configs.append(config)

    def run(batch):
        with registry.load_rig(campaign.rig_ref, search=campaign.rig_search) as rig:
            runs = engine.run_batch(batch, rig, fs=campaign.fs, duration=0.2, seeds=[campaign.seed] * len(batch))
        return [(r.outcome, r.metrics, r.signals) for r in runs]

    mixed = run(configs)
    for b, config in enumerate(configs):
        outcome, metrics, signals = run([config] * len(configs))[b]
        assert mixed[b][0] == outcome, config["controller"]["input"]
        np.testing.assert_equal(mixed[b][1], metrics)  # NaN where a metric has none, in both
        assert signals.keys() == mixed[b][2].keys()
        for name in signals:
            np.testing.assert_array_equal(mixed[b][2][name], signals[name], err_msg=name)


def test_a_ledger_of_five_element_keys_still_resumes(tmp_path, monkeypatch):
    """A Table 3 campaign planned before per-run choices (the input among a key's choices) resumes, its
    four laws in batches of their own."""
    path = _plate_campaign(tmp_path)
    with monkeypatch.context() as old:  # plan as before: every choice splits batches
        old.setattr(checks, "split_choices", lambda found: (found, []))
        old.setattr(runner, "_execute", lambda *args, **kwargs: Outcome())  # planned, nothing run
        runner.start(path, tmp_path / "d", runner.Options(workers=1, stream=io.StringIO()))
    with Ledger.open(tmp_path / "d") as ledger:
        keys = [json.loads(k) for k, _ in planned_batches(ledger, 1)]
    assert len(keys) == 4 and all(len(k) == 5 and "controller.input" in dict(k[3]) for k in keys)
    outcome, _ = runner.resume(tmp_path / "d", runner.Options(workers=1, stream=io.StringIO()))
    assert outcome.complete and outcome.counts == {"no-motion": 4}, outcome  # 50 ms: run, not yet lifted


def test_the_dry_run_labels_mixed_batches(tmp_path):
    campaign = spec.load(_plate_campaign(tmp_path))
    points, _ = spec.plan(campaign)
    text = grid_text(campaign, points, 1, None)
    assert "(plate-mfc; mixed batches: controller.input = v, force, u, current): 1 batches of ≤ 4" in text
