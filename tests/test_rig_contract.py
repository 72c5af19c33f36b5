"""The Rig contract, checked the same way on every rig kind: the three twins, the CAN and serial
rigs over the firmware emulator, and the rigs of docs/writing-a-rig.md (whose code blocks run
here, in order, as written).

Each case builds a fresh rig from a rig file (dict) with optional ``[faults]``/``[limits]``; the
checks are reset/step shapes, clipping to the limits, the safe state, faults from ``t_start`` on,
reproducibility per seed (and batch independence for twins) and the errors of bad input.
"""

from __future__ import annotations

import re
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import serial
from test_campaign_support import campaign_text, write

from labrunner.cli import main
from labrunner.errors import InvalidParameter
from labrunner.rigs import kinds
from labrunner.rigs.base import Rig, RigInfo, Signal
from labrunner.rigs.config import config_from_dict
from labrunner.rigs.registry import load_rig, register_rig, rig_class
from labrunner.rigs.transports.emulator import Emulator, device_link, serve_on_pty, twin_for

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "writing-a-rig.md"
MOTOR_MODEL = {"static_friction": 0.0, "coulomb_friction": 0.0, "backlash": 0.0, "electrical_tau": 0.0}


@pytest.fixture(scope="module")
def doc():
    """The Python blocks of docs/writing-a-rig.md run in one namespace; their kinds stay
    registered for this module's tests only."""
    saved = dict(kinds._registered)
    namespace: dict = {"__name__": "writing_a_rig"}
    text = DOC.read_text(encoding="utf-8")
    for block in re.finditer(r"```python\n(.*?)```", text, flags=re.S):
        padded = "\n" * text.count("\n", 0, block.start(1)) + block[1]  # tracebacks point at the page's lines
        exec(compile(padded, str(DOC), "exec"), namespace)
    yield namespace
    kinds._registered.clear()
    kinds._registered.update(saved)


class LineController:
    """The heater controller of the doc's last example, on a fake serial port: ``P <W>`` steps a
    noise-free heater twin by one sample and answers ``T <°C>``; ``OFF`` switches it off for good."""

    def __init__(self, twin: Rig) -> None:
        self.twin, self.off, self.answers, self.timeout = twin, False, [], None
        twin.reset(1, [0], 1.0)

    def write(self, data: bytes) -> int:
        for line in data.decode().splitlines():
            if line == "OFF":
                self.off = True
            else:
                power = 0.0 if self.off else float(line.split()[1])
                self.answers.append(f"T {float(self.twin.step(np.array([[power]]))[0, 0])!r}\n".encode())
        return len(data)

    def readline(self) -> bytes:
        return self.answers.pop(0) if self.answers else b""

    def close(self) -> None:
        pass


@dataclass(frozen=True)
class Case:
    """A rig kind under test: how to build it from extra rig-file sections, at which rate and batch."""

    name: str
    build: Callable[[dict, pytest.MonkeyPatch], tuple[Rig, Callable[[], None]]]
    fs: float
    batch: int = 3
    sensor_step: float = 0.1  # in the first output's unit
    seeded: bool = True  # the rig's noise follows the seeds (twins, and the emulator's twin behind a link)
    noisy: bool = True  # another seed shows in y within a few ticks (not behind the motor's encoder at rest)


def twin(kind: str) -> Callable:
    def build(extra: dict, monkeypatch) -> tuple[Rig, Callable[[], None]]:
        return load_rig({"rig": {"kind": kind}, **extra}), lambda: None

    return build


def over_can(extra: dict, monkeypatch):
    config = {
        "rig": {"kind": "can", "name": "motor-can"},
        **extra,
        "parameters": {
            "device": "dcmotor",
            "interface": "virtual",
            "channel": f"contract-{uuid.uuid4().hex}",
            "node_id": 3,
            "timeout_s": 0.5,
            "watchdog_periods": 400,
            "model": MOTOR_MODEL,
        },
    }
    emulator = Emulator(twin_for(config_from_dict(config)), device_link(config_from_dict(config)), paced=False).start()
    rig = load_rig(config)
    return rig, lambda: (rig.close(), emulator.stop())


def over_serial(device: str, model: dict) -> Callable:
    def build(extra: dict, monkeypatch):
        config = {
            "rig": {"kind": "serial", "name": f"{device}-serial"},
            **extra,
            "parameters": {"device": device, "timeout_s": 0.5, "watchdog_periods": 400, "model": model},
        }
        port, emulator = serve_on_pty(twin_for(config_from_dict(config)), paced=False)
        config["parameters"]["port"] = port
        rig = load_rig(config)
        return rig, lambda: (rig.close(), emulator.stop())

    return build


def line_heater(extra: dict, monkeypatch):
    device = load_rig({"rig": {"kind": "heater"}, "noise": {"sensor_std": 0.0}})
    monkeypatch.setattr(serial, "serial_for_url", lambda url, **kw: LineController(device))
    rig = load_rig({"rig": {"kind": "line-heater"}, "parameters": {"port": "fake://"}, **extra})
    return rig, rig.close


CASES = [
    Case("dcmotor", twin("dcmotor"), 200.0, noisy=False),
    Case("valve", twin("valve"), 4000.0, sensor_step=2.0),
    Case("plate", twin("plate"), 32000.0, sensor_step=1e-4),
    Case("heater (docs)", twin("heater"), 1.0, sensor_step=1.0),
    Case("can: dcmotor", over_can, 200.0, batch=1, noisy=False),
    Case("serial: dcmotor", over_serial("dcmotor", MOTOR_MODEL), 200.0, batch=1, noisy=False),
    Case("serial: heater (docs)", over_serial("heater", {"tau": 95.0}), 10.0, batch=1, sensor_step=1.0),
    Case("line-heater (docs)", line_heater, 1.0, batch=1, sensor_step=1.0, seeded=False, noisy=False),
]


@pytest.fixture(params=CASES, ids=[c.name for c in CASES])
def case(request, doc):
    return request.param


@pytest.fixture
def make(case, monkeypatch):
    """``make(**sections)`` → a fresh rig of ``case`` with those rig-file sections; closed at the end."""
    cleanups = []

    def build(**sections) -> Rig:
        rig, cleanup = case.build(sections, monkeypatch)
        cleanups.append(cleanup)
        return rig

    yield build
    for cleanup in cleanups:
        cleanup()


def seeds(case: Case) -> list[int]:
    return [11 + i for i in range(case.batch)]


def levels(info: RigInfo) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A mid-range input, and inputs beyond the rig's limits above and below, each (n_inputs,)."""
    lo, hi = info.input_lo, info.input_hi
    mid = np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (lo + hi), np.asarray(info.safe_input) + 0.5)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    return mid, np.where(np.isfinite(hi), hi + span, 1e3), np.where(np.isfinite(lo), lo - span, -1e3)


def drive(rig: Rig, case: Case, u: np.ndarray, ticks: int, seed_list=None) -> tuple[np.ndarray, np.ndarray]:
    """y (ticks + 1, B, n_out) and the applied input (ticks, B, n_in) for a constant input u (n_in,)."""
    seed_list = seeds(case) if seed_list is None else seed_list
    ys = [rig.reset(len(seed_list), seed_list, case.fs)]
    applied = []
    for _ in range(ticks):
        ys.append(rig.step(np.tile(u, (len(seed_list), 1))))
        applied.append(rig.applied_input.copy())
    return np.array(ys), np.array(applied)


# -- the checks, on every case ----------------------------------------------------------------------
def test_reset_and_step_shapes(case, make):
    rig = make()
    n_in, n_out = len(rig.info.inputs), len(rig.info.outputs)
    mid, _, _ = levels(rig.info)
    ys, applied = drive(rig, case, mid, 5)
    assert ys.shape == (6, case.batch, n_out) and applied.shape == (5, case.batch, n_in)
    assert np.isfinite(ys).all() and rig.k == 5 and rig.fs == case.fs
    assert len(rig.info.safe_input) == n_in and rig.info.fs_range[0] <= rig.info.fs_default <= rig.info.fs_range[1]


def test_inputs_are_clipped_to_the_limits_and_to_the_rig_files_limits(case, make):
    rig = make()
    mid, above, below = levels(rig.info)
    np.testing.assert_array_equal(drive(rig, case, above, 2)[1][-1], np.tile(rig.info.input_hi, (case.batch, 1)))
    np.testing.assert_array_equal(drive(rig, case, below, 2)[1][-1], np.tile(rig.info.input_lo, (case.batch, 1)))
    first = rig.info.inputs[0]
    lo, hi = (mid[0] - 0.25 * abs(mid[0]) - 0.1, mid[0] + 0.25 * abs(mid[0]) + 0.1)
    if np.isfinite(first.lo):
        lo = max(lo, first.lo)
    narrowed = make(limits={first.name: [lo, hi]})
    assert narrowed.info.inputs[0].hi == hi
    assert drive(narrowed, case, above, 2)[1][-1][0, 0] == hi


def test_the_safe_state_holds_the_safe_input_for_good(case, make):
    rig = make()
    mid, above, _ = levels(rig.info)
    drive(rig, case, mid, 3)
    mask = np.zeros(case.batch, dtype=bool)
    mask[0] = True
    rig.safe_state(mask)
    safe = np.asarray(rig.info.safe_input)
    np.testing.assert_array_equal(rig.applied_input[0], safe)
    for _ in range(3):
        rig.step(np.tile(above, (case.batch, 1)))
        np.testing.assert_array_equal(rig.applied_input[0], safe)
        np.testing.assert_array_equal(rig.applied_input[1:], np.tile(rig.info.input_hi, (case.batch - 1, 1)))
    np.testing.assert_array_equal(rig.is_safe, mask)
    rig.close()
    assert rig.is_safe.all()


def test_faults_act_from_t_start_on(case, make):
    """Paper 2 Sec. 4.4 on every rig: from t_start on the applied input is (1 + gain)·u + offset,
    and a sensor step adds to the measurement of the same run (same seed: same noise)."""
    k0, ticks = 3, 8
    mid, _, _ = levels(make().info)
    offset, gain = 0.05 * (abs(mid) + 1.0), -0.5
    clean_y, clean_u = drive(make(), case, mid, ticks)
    faults = {"t_start": k0 / case.fs, "actuator_offset": offset.tolist(), "actuator_gain": gain}
    _, faulty_u = drive(make(faults=faults), case, mid, ticks)
    np.testing.assert_array_equal(faulty_u[:k0], clean_u[:k0])
    np.testing.assert_allclose(
        faulty_u[k0:], np.broadcast_to((1 + gain) * mid + offset, faulty_u[k0:].shape), rtol=1e-15
    )
    stepped_y, _ = drive(make(faults={"t_start": k0 / case.fs, "sensor_step": case.sensor_step}), case, mid, ticks)
    np.testing.assert_array_equal(stepped_y[:k0], clean_y[:k0])  # y[k] is the measurement at t = k/fs
    scale = np.abs(clean_y).max() + case.sensor_step
    np.testing.assert_allclose(stepped_y[k0:] - clean_y[k0:], case.sensor_step, rtol=0, atol=1e-12 * scale)


def test_a_run_is_reproducible_from_its_seed_alone(case, make):
    mid, _, _ = levels(make().info)
    first, _ = drive(make(), case, mid, 10)
    np.testing.assert_array_equal(drive(make(), case, mid, 10)[0], first)
    if case.noisy:
        other, _ = drive(make(), case, mid, 10, seed_list=[s + 100 for s in seeds(case)])
        assert not np.array_equal(other, first)
    for i, seed in enumerate(seeds(case) if case.batch > 1 else []):  # a batch is B single runs
        alone, _ = drive(make(), case, mid, 10, seed_list=[seed])
        np.testing.assert_allclose(alone[:, 0], first[:, i], rtol=1e-13, atol=0)


def test_bad_batches_seeds_rates_and_overrides_are_refused(case, make):
    rig = make()
    lo, hi = rig.info.fs_range
    with pytest.raises(InvalidParameter) as err:
        rig.reset(case.batch, [0] * (case.batch + 1), case.fs)
    assert err.value.field == "seeds"
    with pytest.raises(InvalidParameter) as err:
        rig.reset(case.batch, seeds(case), 2.0 * hi + 1.0)
    assert err.value.field == "fs"
    with pytest.raises(InvalidParameter) as err:
        rig.reset(case.batch, seeds(case), case.fs, overrides={"no_such_parameter": 1.0})
    assert err.value.field == "overrides.no_such_parameter"
    if not rig.info.simulated:
        with pytest.raises(InvalidParameter) as err:
            rig.reset(2, [0, 1], case.fs)
        assert err.value.field == "batch"
    rig.reset(case.batch, seeds(case), case.fs)  # still usable after refused input
    assert rig.step(np.tile(levels(rig.info)[0], (case.batch, 1))).shape == (case.batch, len(rig.info.outputs))


# -- the contract itself ------------------------------------------------------------------------------
class Bare(Rig):
    """Steps, but says nothing about what it is."""

    def _reset(self, batch, seeds, overrides):
        return np.zeros((batch, 1))

    def _step(self, u):
        return u.copy()


class Echo(Bare):
    """The smallest complete rig: everything else from the base class's defaults."""

    @classmethod
    def nominal_info(cls, name, description, parameters):
        return RigInfo(name, "echo", (Signal("u", "1", -1.0, 1.0),), (Signal("y", "1"),), (1.0, 100.0), 10.0, (0.0,))


class PlainHook(Echo):
    def validate_noise(self, raw, path="noise"):  # not a class method: the loader calls it on the class
        return {}


def test_registration_checks_a_class_against_the_contract(monkeypatch):
    monkeypatch.setattr(kinds, "_registered", {})
    with pytest.raises(InvalidParameter, match="does not implement nominal_info"):
        register_rig("bare", Bare)
    with pytest.raises(InvalidParameter, match="validate_noise must be a classmethod"):
        register_rig("plain", PlainHook)
    with pytest.raises(InvalidParameter, match="is not a Rig class"):
        register_rig("dict", dict)
    register_rig("bare-lazy", f"{__name__}:Bare")  # a "module:Class" target is checked when first imported
    with pytest.raises(InvalidParameter, match="does not implement nominal_info"):
        rig_class("bare-lazy")


def test_a_direct_subclass_runs_on_the_defaults(monkeypatch):
    monkeypatch.setattr(kinds, "_registered", {})
    register_rig("echo", Echo)
    with load_rig({"rig": {"kind": "echo"}}) as rig:
        rig.reset(2, [0, 1], 10.0)
        np.testing.assert_array_equal(rig.step(np.array([[0.5], [3.0]])), [[0.5], [1.0]])  # clipped to [-1, 1]
        with pytest.raises(InvalidParameter, match="this rig has no per-run parameters") as err:
            rig.reset(1, [0], 10.0, overrides={"gain": 2.0})
        assert err.value.field == "overrides.gain"
    for section in ("parameters", "noise"):
        with pytest.raises(InvalidParameter, match="unknown key; allowed: no keys") as err:
            load_rig({"rig": {"kind": "echo"}, section: {"gain": 2.0}})
        assert err.value.field == f"<dict>: {section}.gain"


def test_a_remote_device_is_any_registered_kind_that_is_not_remote(doc):
    with pytest.raises(InvalidParameter, match=r"must be one of \[.*'dcmotor'.*'heater'.*\], got 'serial'") as err:
        config_from_dict({"rig": {"kind": "can"}, "parameters": {"device": "serial"}})
    assert err.value.field == "<dict>: parameters.device"
    assert config_from_dict({"rig": {"kind": "can"}, "parameters": {"device": "heater"}}).info.kind == "heater"


def test_the_docs_heater_follows_the_analytic_step_response(doc):
    """τ Ṫ = −(T − T_amb) + K P under a held step P: T(t) = T_amb + K P (1 − e^(−t/τ))."""
    tau, gain, ambient, power, fs = 90.0, 0.48, 20.0, 50.0, 2.0
    rig = load_rig(
        {
            "rig": {"kind": "heater"},
            "parameters": {"tau": tau, "gain": gain, "ambient": ambient},
            "noise": {"sensor_std": 0.0},
        }
    )
    ys, _ = drive(rig, Case("heater", twin("heater"), fs, batch=1), np.array([power]), 400)
    t = np.arange(401) / fs
    np.testing.assert_allclose(ys[:, 0, 0], ambient + gain * power * (1.0 - np.exp(-t / tau)), rtol=1e-12)


# -- campaigns check their points through the rig's own schema (issue 18) -----------------------------
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("\n[rig_parameters]\nstatic_friction = -1.0\n", "rig_parameters.static_friction: must be >= 0, got -1"),
        ("\n[rig_parameters]\nencoder_counts = 0.5\n", "rig_parameters.encoder_counts: must be an integer, got 0.5"),
        (
            "\n[rig_parameters]\ncoulomb_friction = 2.0\n",
            "rig_parameters.coulomb_friction: must be <= static_friction = 0.8 V, got 2",
        ),
        ("", 'rig_parameters.b: must be > 0, got -5 (at grid point {"rig_parameters.b":-5.0})'),
    ],
)
def test_rig_parameters_and_grid_values_are_checked_before_anything_is_created(project, capsys, extra, message):
    grid = (
        '"rig_parameters.b" = { values = [100.0, -5.0] }' if not extra else '"controller.k_p" = { values = [1.0, 2.0] }'
    )
    path = write(project / "c.toml", campaign_text(grid=grid, extra=extra))
    assert main(["run", str(path), "--out", "data/c"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("labrunner run: error: ") and err.endswith(message) and "\n" not in err
    assert not (project / "data").exists()


@pytest.mark.parametrize(
    ("rig_file", "message"),
    [
        ('[rig]\nkind = "dcmotor"\n[parameters]\na = -1\n', "rigs/bad.toml: parameters.a: must be > 0, got -1"),
        (
            '[rig]\nkind = "plate"\n[faults]\nt_start = 0.1\nsensor_step = [1e-4, 0.0, 0.0]\n',
            "rigs/bad.toml: faults.sensor_step: needs 1 or 4 values, got 3",
        ),
    ],
)
def test_rig_file_errors_reach_the_user_with_the_loaders_context(project, capsys, rig_file, message):
    write(project / "rigs" / "bad.toml", rig_file)
    path = write(project / "c.toml", campaign_text(rig="rigs/bad.toml"))
    assert main(["run", str(path), "--out", "data/c"]) == 2
    assert capsys.readouterr().err.strip() == f"labrunner run: error: {message}"
    assert not (project / "data").exists()
