"""``labrunner conform``: the conformance vectors and the protocol's edge cases against the
emulated device — all pass on the emulator; an emulator with a wrong law and broken protocol
handling fails exactly the checks those faults break, and ``conform`` exits non-zero."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from labrunner.rigs.device import conform, description, vectors
from labrunner.rigs.device.description import DescriptionError
from tests.test_deviceloop_link import ROOT, emulator_process, rig_file, rig_toml

MOTOR_CASES = conform.cases_for("dcmotor")


def _conform(tmp_path: Path, config: dict, *args: str) -> tuple[int, dict]:
    path = tmp_path / "rig.toml"
    path.write_text(rig_toml(config))
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "conform", str(path), "--json", *args],
        capture_output=True, text=True, cwd=ROOT, timeout=900,
    )  # fmt: skip
    return done.returncode, json.loads(done.stdout)


def test_every_description_conform_sends_to_be_refused_is_refused_by_the_reference_decoder():
    good = vectors.build(vectors.CASES["mfc1-motor-velocity"]).data
    description.decode(good)
    broken = conform._broken(good)
    assert [what for what, _ in broken] == [
        "bad CRC", "another version", "bad magic", "wrong length", "unknown record", "unknown controller kind",
        "wrong channel counts",
    ]  # fmt: skip
    for _, data in broken[:5]:
        with pytest.raises(DescriptionError):
            description.decode(data)
    assert description.decode(broken[5][1]).kind == "????"  # decodes: the device refuses the kind
    assert description.decode(broken[6][1]).n_outputs == 2  # decodes: the device refuses the counts


def test_the_vectors_of_each_rig_kind():
    assert MOTOR_CASES[0] == "mfc1-motor-velocity" and "mfc1-motor-du_dt-abort" in MOTOR_CASES
    assert conform.cases_for("valve")[:2] == ["mfc1-valve-i_min", "valve-ffc"]
    assert len(conform.cases_for("valve")) == 12 and len(conform.cases_for("plate")) == 17


def test_an_unknown_case_is_refused_in_one_line_before_the_link_opens():
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "conform", str(ROOT / "rigs" / "dcmotor-can.toml"), "--case", "plate-mbc"],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 2 and "--case: must be one of mfc1-motor-velocity" in done.stderr
    assert "for a dcmotor, got 'plate-mbc'" in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_a_rig_file_without_a_device_is_refused_in_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "labrunner", "conform", str(ROOT / "rigs" / "dcmotor-sim.toml")],
        capture_output=True, text=True, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode != 0 and "conform checks can or serial rig files" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_the_emulated_device_passes_every_check(tmp_path):
    with emulator_process(rig_file("motor-mfc1", "canfd")) as config:
        code, report = _conform(tmp_path, config)
    assert code == 0 and report["passed"], [c for c in report["checks"] if not c["passed"]]
    names = [c["name"] for c in report["checks"]]
    assert names[0] == "handshake" and [f"vector {c}" for c in MOTOR_CASES] == names[1 : 1 + len(MOTOR_CASES)]
    assert {"reject bad CRC", "hello version", "STOP mid-run", "SAFE mid-run", "watchdog"} <= set(names)


@pytest.mark.slow
def test_the_emulated_plate_passes_its_vectors(tmp_path):
    with emulator_process(rig_file("plate-mfc", "canfd")) as config:
        code, report = _conform(tmp_path, config, "--no-protocol")
    assert code == 0, report
    assert [c["name"] for c in report["checks"]] == ["handshake"] + [f"vector {c}" for c in conform.cases_for("plate")]


@pytest.mark.slow
def test_a_device_with_a_wrong_law_and_broken_protocol_fails_exactly_those_checks(tmp_path):
    faults = ("--fault-law", "gamma=1.02")
    for fault in ("no-crc-check", "any-version", "ignore-stop", "no-watchdog"):
        faults += ("--fault-protocol", fault)
    with emulator_process(rig_file("motor-mfc1", "canfd"), faults) as config:
        code, report = _conform(tmp_path, config)
    assert code == 1 and not report["passed"]
    failed = {c["name"] for c in report["checks"] if not c["passed"]}
    law = {f"vector {c}" for c in MOTOR_CASES if not c.startswith("open-loop")}  # open loop has no gamma
    assert failed == law | {"reject bad CRC", "reject another version", "STOP mid-run", "SAFE mid-run", "watchdog"}
    details = {c["name"]: c["detail"] for c in report["checks"]}
    assert all("law diverged@tick" in details[name] for name in law)
    assert "the device ran it" in details["reject bad CRC"]


@pytest.mark.slow
def test_a_device_faster_than_the_silence_is_tried_again_on_a_longer_run(monkeypatch):
    """A free-running emulator ran the 60 000 ticks before the host had been silent for the
    watchdog's second in 1 of 2 tries: the check failed a device that had done nothing wrong. Made
    certain here with a short run: the check then runs one long enough at the rate the device
    showed, where the watchdog fires (a device without one still fails: the test above)."""
    from labrunner.rigs.config import config_from_dict
    from labrunner.rigs.registry import load_rig

    monkeypatch.setattr(conform, "LONG_TICKS", 2000)
    with emulator_process(rig_file("motor-mfc1", "canfd")) as config:
        rig = load_rig(config_from_dict(config))
        with rig:
            rig.handshake()
            check = conform._interrupted(rig, vectors.CASES[MOTOR_CASES[0]], "watchdog")
    assert check.passed and "no message from the host" in check.detail, check.detail
    assert "it had completed all 2000 ticks first" in check.detail


def test_a_completed_watchdog_run_is_tried_again_only_where_its_progress_rate_does_not_outlast_the_silence():
    """3 s from the run's first answer to the end of the host's silence: 60 000 ticks at 15 000/s
    (4 s) outlast it, so the completed run is conclusive; at 45 000/s (1.3 s) they do not, and the
    check runs once more with 3 s of ticks; without PROGRESS, 10× that at the rate seen at least."""
    assert conform.LONG_TICKS == 60_000 and conform.STOP_AFTER_S + 2.5 * conform.WATCHDOG_S == 3.0
    ticks, detail = conform._outlasting(15_000, 5_000)
    assert ticks == 60_000 and "15000 ticks/s its PROGRESS showed" in detail
    ticks, detail = conform._outlasting(45_000, 11_000)
    assert ticks == 135_000 and "so again with 135000" in detail
    assert conform._outlasting(0, 11_000)[0] == 330_000
    assert conform._outlasting(0, 1_000)[0] == 60_000  # never shorter than the first run


def test_a_retry_the_device_outran_too_is_sized_by_the_retrys_own_rate():
    """In a loaded suite an emulator sent no PROGRESS in a 2000-tick run (~638 ticks/s to its verdict)
    and then completed the 19 128-tick retry too: ten times its first rate was not enough. After a
    completed run of ``ran`` ticks, the next is sized from that run's own rate, never shorter."""
    assert conform._outlasting(0, 638, 2000)[0] == 19_140  # 10 × 638/s × 3 s
    ticks, detail = conform._outlasting(8_000, 6_000, 19_140)  # the retry's PROGRESS: 8000/s × 3 s
    assert ticks == 24_000 and "completed all 19140 ticks first" in detail
    ticks, detail = conform._outlasting(6_000, 5_000, 19_140)  # 18 000 ≤ 19 140: conclusive
    assert ticks == 19_140 and "outlasted" in detail
