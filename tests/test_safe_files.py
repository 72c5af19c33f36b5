"""Issue 36: every file labrunner creates, rewrites or renames in a campaign directory refuses a
symbolic link or another non-regular file planted at its name (labrunner/safefs.py): the lock,
the ledger and its -wal/-shm, the campaign copy, runs/ and the logs, quarantine/, and analyse's
report, its metrics.csv/parquet, figures and their temporary files. Each case plants a link to a
victim file outside the campaign and checks the one-line refusal and the victim's bytes."""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_campaign_support import campaign_text, write

from labrunner import safefs
from labrunner.cli import main
from labrunner.logs import write_run

GRID = '"controller.k_p" = { values = [1.0, 10.0] }'
VICTIM_TEXT = b"another user's file: must never change\n"


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished two-point campaign (its directory), run once for the module."""
    from test_campaign_support import MOTOR_RIG

    root = tmp_path_factory.mktemp("safe")
    (root / "pyproject.toml").write_text("[project]\nname = 'lab'\n")
    (root / "rigs").mkdir()
    (root / "rigs" / "motor.toml").write_text(MOTOR_RIG)
    path = write(root / "s.toml", campaign_text("s", grid=GRID, duration=0.5))
    assert main(["run", str(path), "--out", str(root / "done"), "--workers", "1"]) == 0
    return root / "done"


@pytest.fixture
def campaign(finished: Path, tmp_path: Path) -> Path:
    """A copy of the finished campaign (its report not yet written)."""
    copy = tmp_path / "c"
    shutil.copytree(finished, copy, symlinks=True)
    return copy


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    path = tmp_path / "victim.txt"
    path.write_bytes(VICTIM_TEXT)
    return path


def _plant(path: Path, victim: Path) -> None:
    path.unlink(missing_ok=True)
    path.symlink_to(victim)


def _refused(args: list[str], capsys, what: Path) -> None:
    code = main(args)
    err = capsys.readouterr().err
    assert code != 0, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{what} is a symbolic link" in err, err


@pytest.mark.parametrize("command", ["resume", "repair --force"])
def test_a_linked_lock_is_refused_and_its_target_untouched(campaign, victim, capsys, command):
    _plant(campaign / ".lock", victim)
    _refused([*command.split(), str(campaign)], capsys, campaign / ".lock")
    assert victim.read_bytes() == VICTIM_TEXT
    assert (campaign / ".lock").is_symlink()


def test_status_reads_no_linked_lock(campaign, victim, capsys):
    _plant(campaign / ".lock", victim)
    _refused(["status", str(campaign)], capsys, campaign / ".lock")
    assert victim.read_bytes() == VICTIM_TEXT


def test_run_into_a_folder_whose_lock_is_a_link_refuses(project, victim, capsys):
    out = project / "out"
    out.mkdir()
    _plant(out / ".lock", victim)
    path = write(project / "r.toml", campaign_text("r", grid=GRID, duration=0.5))
    code = main(["run", str(path), "--out", str(out), "--workers", "1"])
    err = capsys.readouterr().err
    assert code != 0 and err.count("\n") == 1, err
    assert victim.read_bytes() == VICTIM_TEXT
    assert not (out / "ledger.sqlite").exists()


@pytest.mark.parametrize("name", ["ledger.sqlite", "ledger.sqlite-wal", "ledger.sqlite-shm"])
def test_resume_refuses_a_linked_ledger_or_side_file(campaign, finished, tmp_path, capsys, name):
    other = tmp_path / "other"  # another campaign, whose ledger a link would make resume change
    shutil.copytree(finished, other)
    target = other / name
    if not target.exists():
        target.write_bytes(b"")
    before = {p.name: p.read_bytes() for p in other.iterdir() if p.is_file()}
    _plant(campaign / name, target)
    _refused(["resume", str(campaign)], capsys, campaign / name)
    assert {p.name: p.read_bytes() for p in other.iterdir() if p.is_file()} == before


def test_resume_refuses_a_linked_campaign_copy(campaign, victim, capsys):
    _plant(campaign / "campaign.toml", victim)
    _refused(["resume", str(campaign)], capsys, campaign / "campaign.toml")
    assert victim.read_bytes() == VICTIM_TEXT


def test_recovery_refuses_a_linked_quarantine(campaign, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (campaign / "quarantine").symlink_to(elsewhere, target_is_directory=True)
    stray = campaign / "runs" / ".tmp-0123456789abcdef-1-abcd.mcap"  # a killed writer's: to be quarantined
    stray.write_bytes(b"half a log")
    _refused(["resume", str(campaign)], capsys, campaign / "quarantine")
    assert list(elsewhere.iterdir()) == []
    assert stray.read_bytes() == b"half a log"


@pytest.mark.parametrize(
    "name", ["metrics.csv", "metrics.parquet", "index.html", "sweep.png", ".metrics.csv.tmp", ".sweep.png.tmp"]
)
def test_analyse_refuses_a_linked_report_file(campaign, victim, capsys, name):
    report = campaign / "report"
    report.mkdir()
    _plant(report / name, victim)
    code = main(["analyse", str(campaign)])
    err = capsys.readouterr().err
    if name.startswith("."):  # the old fixed temporary names: no longer used, never written through
        assert code == 0, err
        assert (report / "metrics.csv").is_file() and not (report / "metrics.csv").is_symlink()
    else:
        assert code != 0 and f"{report / name} is a symbolic link" in err, err
    assert victim.read_bytes() == VICTIM_TEXT
    assert not [p for p in report.iterdir() if p.name.endswith(".tmp") and not p.is_symlink()]


def test_analyse_refuses_a_linked_report_folder(campaign, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (campaign / "report").symlink_to(elsewhere, target_is_directory=True)
    code = main(["analyse", str(campaign)])
    err = capsys.readouterr().err
    assert code != 0 and "report is a symbolic link" in err, err
    assert list(elsewhere.iterdir()) == []


def test_a_log_is_never_written_through_a_link_or_into_a_fifo(tmp_path, victim):
    signals = {"y": np.zeros(4)}
    channels = {"y": {"role": "output", "unit": "m"}}
    outcome = {"status": "completed", "n_samples": 4}
    link = tmp_path / "run.mcap"
    link.symlink_to(victim)
    with pytest.raises(safefs.UnsafePath, match="is a symbolic link"):
        write_run(link, metadata={}, signals=signals, fs=10.0, channels=channels, outcome=outcome)
    assert victim.read_bytes() == VICTIM_TEXT
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    with pytest.raises(safefs.UnsafePath, match="is a FIFO"):  # refused at once, not blocked on
        write_run(fifo, metadata={}, signals=signals, fs=10.0, channels=channels, outcome=outcome)


def test_a_log_is_never_published_over_a_link(tmp_path, victim):
    tmp = tmp_path / ".tmp-x.mcap"
    tmp.write_bytes(b"log")
    final = tmp_path / "x.mcap"
    final.symlink_to(victim)
    with pytest.raises(safefs.UnsafePath):
        safefs.replace(tmp, final)
    assert final.is_symlink() and victim.read_bytes() == VICTIM_TEXT and tmp.exists()


def test_temporary_files_are_fresh_and_unpredictable(tmp_path):
    names = set()
    for _ in range(20):
        fd, path = safefs.temp_file(tmp_path, ".metrics.csv.", ".tmp")
        os.close(fd)
        assert path.parent == tmp_path and stat.S_ISREG(os.lstat(path).st_mode)
        names.add(path.name)
    assert len(names) == 20  # each a new name: nothing planted in advance can be hit


def test_atomic_write_leaves_nothing_behind_when_it_fails(tmp_path):
    final = tmp_path / "index.html"

    class Boom(Exception):
        pass

    with pytest.raises(Boom), safefs.atomic_path(final) as tmp:
        tmp.write_text("half")
        raise Boom
    assert list(tmp_path.iterdir()) == []


def test_a_directory_or_fifo_at_the_lock_is_refused(campaign, capsys):
    (campaign / ".lock").unlink()
    os.mkfifo(campaign / ".lock")
    code = main(["resume", str(campaign)])
    err = capsys.readouterr().err
    assert code != 0 and ".lock is a FIFO" in err, err


def _as_reader_without_write_access(args: list[str]) -> subprocess.CompletedProcess:
    """Run ``python -m labrunner ARGS`` without the power to write where the mode bits forbid it:
    as root (whom chmod does not stop), with the capabilities that override file modes dropped
    from the bounding set (``setpriv``); as another user, as that user."""
    command = [sys.executable, "-m", "labrunner", *args]
    if os.geteuid() == 0:
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            if os.environ.get("LABRUNNER_CI") == "1":
                pytest.fail("setpriv (util-linux) is needed to test a read-only campaign as root")
            pytest.skip("setpriv (util-linux) not installed: cannot drop root's file-mode override")
        command = [setpriv, "--bounding-set=-dac_override,-dac_read_search,-fowner", *command]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.run(command, capture_output=True, text=True, timeout=120, env=env)


def test_a_read_only_copy_without_wal_and_shm_is_read_not_called_damaged(campaign, tmp_path):
    for side in ("ledger.sqlite-wal", "ledger.sqlite-shm"):
        (campaign / side).unlink(missing_ok=True)
    for path in [campaign, *campaign.rglob("*")]:
        path.chmod(path.stat().st_mode & ~0o222)
    try:
        probe = _as_reader_without_write_access(["status", "--json", str(campaign)])
        assert probe.returncode == 0, probe.stderr
        assert "damaged" not in probe.stderr and "repair" not in probe.stderr
        assert json.loads(probe.stdout)["outcomes"]["completed"] == 2
        written = _as_reader_without_write_access(["analyse", str(campaign)])  # its report cannot be written
        assert written.returncode == 1, written.stderr
        assert written.stderr.splitlines()[-1].endswith(f"{campaign / 'report'}: Permission denied")
        assert "damaged" not in written.stderr
        elsewhere = _as_reader_without_write_access(["analyse", str(campaign), "--out", str(tmp_path / "mine")])
        assert elsewhere.returncode == 0, elsewhere.stderr
        assert (tmp_path / "mine" / "metrics.csv").is_file()
    finally:
        for path in [campaign, *campaign.rglob("*")]:
            path.chmod(path.stat().st_mode | 0o200)
