"""Rig files, the registry and faults: validation errors name the key, entry points extend the registry."""

from __future__ import annotations

import json
from importlib.metadata import EntryPoint
from pathlib import Path

import numpy as np
import pytest

from labrunner.errors import InvalidParameter
from labrunner.rigs import kinds, registry
from labrunner.rigs.base import Faults, RigInfo, Signal
from labrunner.rigs.config import Param, RigConfig, config_from_dict, load_rig_config
from labrunner.rigs.registry import load_rig, register_rig, rig_class, rig_kinds
from labrunner.rigs.sim import SimRig
from labrunner.rigs.sim.dcmotor import DCMotorTwin

ROOT = Path(__file__).resolve().parents[1]


def write_rig(tmp_path: Path, name: str, text: str) -> Path:
    (tmp_path / "rigs").mkdir(exist_ok=True)
    path = tmp_path / "rigs" / f"{name}.toml"
    path.write_text(text)
    return path


def error_of(fn, *args, **kw) -> InvalidParameter:
    with pytest.raises(InvalidParameter) as info:
        fn(*args, **kw)
    return info.value


def test_shipped_rig_files_load():
    for name in ("dcmotor-sim", "dcmotor-frictionless", "valve-sim", "dcmotor-can"):
        config = load_rig_config(name, search=[ROOT / "rigs"])
        assert isinstance(config, RigConfig) and config.name == name
        json.dumps(config.to_dict())
    sim = load_rig_config(ROOT / "rigs" / "dcmotor-sim.toml")
    assert sim.safety["max_du_dt"] == 120.0 and sim.kind == "dcmotor"


def test_error_names_file_and_key(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write_rig(tmp_path, "dcmotor-sim", '[rig]\nkind = "dcmotor"\n[parameters]\na = -1\n')
    err = error_of(load_rig_config, "dcmotor-sim", search=[tmp_path / "rigs"])
    assert err.field == "rigs/dcmotor-sim.toml: parameters.a"
    assert str(err) == "rigs/dcmotor-sim.toml: parameters.a: must be > 0, got -1"


@pytest.mark.parametrize(
    ("text", "field", "fragment"),
    [
        ('[rig]\nkind = "dcmotor"\n[parameters]\nfoo = 1\n', "parameters.foo", "unknown key"),
        ('[rig]\nkind = "dcmotor"\n[extra]\nx = 1\n', "extra", "unknown section"),
        ('[rig]\nkind = "warp-drive"\n', "rig.kind", "unknown rig kind"),
        ("[parameters]\na = 1\n", "rig.kind", "is required"),
        ('[rig]\nkind = "dcmotor"\ncolour = "red"\n', "rig.colour", "unknown key"),
        ('[rig]\nkind = "dcmotor"\n[parameters]\nencoder_counts = 20.5\n', "parameters.encoder_counts", "integer"),
        ('[rig]\nkind = "dcmotor"\n[parameters]\nb = "big"\n', "parameters.b", "must be a number"),
        ('[rig]\nkind = "dcmotor"\n[parameters]\ncoulomb_friction = 2.0\n', "parameters.coulomb_friction", "static"),
        ('[rig]\nkind = "dcmotor"\n[noise]\ninput_v = -0.1\n', "noise.input_v", "must be >= 0"),
        ('[rig]\nkind = "dcmotor"\n[limits]\nu = [-20, 20]\n', "limits.u", "must lie in [-12, 12]"),
        ('[rig]\nkind = "dcmotor"\n[limits]\nspeed = [0, 1]\n', "limits.speed", "unknown key"),
        ('[rig]\nkind = "dcmotor"\n[limits]\nfs = [100, 50]\n', "limits.fs", "lo < hi"),
        ('[rig]\nkind = "dcmotor"\n[limits]\nfs_default = 5e5\n', "limits.fs_default", "must lie in"),
        ('[rig]\nkind = "dcmotor"\n[faults]\nactuator_offset = 1.0\n', "faults.t_start", "required"),
        (
            '[rig]\nkind = "dcmotor"\n[faults]\nt_start = 1\nsensor_step = [1, 2]\n',
            "faults.sensor_step",
            "needs 1 value, got 2",
        ),
        ('[rig]\nkind = "dcmotor"\n[faults]\nt_start = 1\nactuator_gain = -1.5\n', "faults.actuator_gain", "> -1"),
        ('[rig]\nkind = "dcmotor"\n[safety]\nmax_du_dt = -5\n', "safety.max_du_dt", "must be > 0"),
        ('[rig]\nkind = "dcmotor"\n[safety]\nbogus = 1\n', "safety.bogus", "unknown key"),
        ('[rig]\nkind = "valve"\n[parameters]\nsensor_min = 30\n', "parameters.sensor_min", "sensor_max"),
        ('[rig]\nkind = "valve"\n[parameters]\npilot_threshold = 1.5\n', "parameters.pilot_threshold", "in [0, 0.95]"),
    ],
)
def test_validation_errors_name_the_key(tmp_path, text, field, fragment):
    path = write_rig(tmp_path, "bad", text)
    err = error_of(load_rig_config, path)
    assert err.field == f"{path}: {field}"
    assert fragment in str(err)


def test_invalid_toml_and_missing_files(tmp_path):
    path = write_rig(tmp_path, "broken", "[rig\nkind=")
    assert "is not valid TOML" in str(error_of(load_rig_config, path))
    assert error_of(load_rig_config, "nope", search=[tmp_path / "rigs"]).field == "rig"
    assert load_rig_config("valve-sim", search=[tmp_path / "rigs"]).kind == "valve"  # falls back to ./rigs
    assert error_of(load_rig_config, tmp_path / "missing.toml").field == "rig"


def test_search_order_prefers_first_directory(tmp_path):
    write_rig(tmp_path, "dcmotor-sim", '[rig]\nkind = "dcmotor"\ndescription = "mine"\n')
    assert load_rig_config("dcmotor-sim", search=[tmp_path / "rigs", ROOT / "rigs"]).description == "mine"
    assert load_rig_config("dcmotor-sim", search=[ROOT / "rigs", tmp_path / "rigs"]).description != "mine"


def test_limits_narrow_the_rig_info_and_input_clipping():
    config = config_from_dict({"rig": {"kind": "dcmotor"}, "limits": {"u": [-6, 6], "fs": [100, 500]}})
    rig = load_rig(config)
    assert (rig.info.inputs[0].lo, rig.info.inputs[0].hi) == (-6, 6)
    assert rig.info.fs_range == (100, 500) and rig.info.fs_default == 200
    rig.reset(1, [0], 200.0)
    rig.step(np.array([[12.0]]))
    assert rig.applied_input[0, 0] == 6.0
    with pytest.raises(InvalidParameter, match="fs"):
        rig.reset(1, [0], 1000.0)


def test_overrides_are_validated_per_run():
    rig = DCMotorTwin()
    assert error_of(rig.reset, 2, [0, 1], 200.0, {"a": np.array([1.0, -1.0])}).field == "overrides.a"
    assert error_of(rig.reset, 2, [0, 1], 200.0, {"zeta": 1.0}).field == "overrides.zeta"
    assert error_of(rig.reset, 2, [0, 1], 200.0, {"a": np.ones(3)}).field == "overrides.a"
    err = error_of(rig.reset, 1, [0], 200.0, {"coulomb_friction": 5.0})
    assert err.field == "overrides.coulomb_friction"
    rig.reset(3, [0, 1, 2], 200.0, {"a": np.array([np.nan, 20.0, np.nan])})  # NaN: the file's value
    np.testing.assert_array_equal(rig.p["a"], [40.8, 20.0, 40.8])  # the default (calibrated) a


def test_faults_section_maps_onto_base_faults():
    """Paper 2 Sec. 4.4 faults from a rig file: additive actuator fault from t_start on."""
    config = config_from_dict(
        {
            "rig": {"kind": "dcmotor"},
            "parameters": {
                "a": 39.44,
                "b": 108.55,
                "static_friction": 0.0,
                "coulomb_friction": 0.0,
                "backlash": 0.0,
                "electrical_tau": 0.0,
                "encoder_counts": 0,
            },
            "noise": {"input_v": 0.0},
            "faults": {"t_start": 0.5, "actuator_offset": 2.0, "sensor_step": [0.25]},
        }
    )
    assert config.faults == Faults(0.5, (2.0,), (0.0,), (0.25,))
    rig = load_rig(config)
    ys = [rig.reset(1, [0], 100.0)[0, 0]] + [rig.step(np.zeros((1, 1)))[0, 0] for _ in range(100)]
    ys = np.array(ys)
    assert np.all(ys[:50] == 0.0)
    t = np.arange(1, 51) / 100.0
    expected = 108.55 * 2.0 / 39.44 * (t - (1 - np.exp(-39.44 * t)) / 39.44)
    np.testing.assert_allclose(ys[51:], expected[:50] + 0.25, atol=1e-9)
    assert ys[50] == 0.25  # the sensor step shows from t_start on, before the plant moved


def test_valve_multiplicative_fault():
    config = config_from_dict({"rig": {"kind": "valve"}, "faults": {"t_start": 0.0, "actuator_gain": -0.5}})
    rig = load_rig(config)
    rig.reset(1, [0], 4000.0)
    rig.step(np.array([[1.0]]))
    assert rig.applied_input[0, 0] == 0.5


def test_registry_builtins_and_lazy_import():
    kinds = rig_kinds()
    assert kinds["plate"] == "labrunner.rigs.sim.plate:PlateTwin"
    assert {"dcmotor", "valve", "plate", "can", "serial"} <= set(kinds)
    assert rig_class("dcmotor") is DCMotorTwin
    assert error_of(rig_class, "nope").field == "kind"
    with pytest.raises(InvalidParameter, match="module:Class"):
        register_rig("bad", "no_colon")


class ToyRig(SimRig):
    """A one-signal integrator registered through an entry point in the tests."""

    KIND = "toy"
    PARAMETERS = {"gain": Param(2.0, "1/s", "integrator gain", lo=0.0)}
    NOISE = {}

    @classmethod
    def nominal_info(cls, name, description, parameters):
        return RigInfo(name, cls.KIND, (Signal("u", "1", -1, 1),), (Signal("y", "1"),), (1.0, 1e3), 10.0, (0.0,))

    def _reset(self, batch, seeds, overrides):
        self.gain = self.per_run(batch, overrides)["gain"]
        self.y = np.zeros(batch)
        return self.y[:, None]

    def _step(self, u):
        self.y = self.y + self.gain * u[:, 0] / self.fs
        return self.y[:, None]


def test_entry_point_extends_registry(monkeypatch, tmp_path, request):
    ep = EntryPoint(name="toy", value=f"{__name__}:ToyRig", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(kinds, "entry_points", lambda group: [ep] if group == registry.ENTRY_POINT_GROUP else [])
    kinds._plugin_kinds.cache_clear()  # looked up once a process: again, with the plug-in installed
    request.addfinalizer(kinds._plugin_kinds.cache_clear)
    assert rig_kinds()["toy"] == f"{__name__}:ToyRig"
    path = write_rig(tmp_path, "toy", '[rig]\nkind = "toy"\n[parameters]\ngain = 5.0\n')
    rig = load_rig(path)
    rig.reset(1, [0], 10.0)
    assert rig.step(np.array([[1.0]]))[0, 0] == pytest.approx(0.5)
    assert error_of(
        load_rig, write_rig(tmp_path, "toy2", '[rig]\nkind = "toy"\n[parameters]\ngain = -1\n')
    ).field.endswith("parameters.gain")


def test_register_rig_at_run_time(monkeypatch):
    monkeypatch.setattr(kinds, "_registered", {})
    register_rig("toy-rt", f"{__name__}:ToyRig")
    assert rig_class("toy-rt") is ToyRig


@pytest.mark.parametrize(
    ("kind", "fs", "u", "actuator", "sensor"),
    [
        ("dcmotor", 200.0, [3.0], {"actuator_offset": 1.5, "actuator_gain": -0.5}, {"sensor_step": 0.1}),
        ("valve", 4000.0, [0.6], {"actuator_offset": 0.05, "actuator_gain": -0.5}, {"sensor_step": 2.0}),
        (
            "plate",
            32000.0,
            [2.0, 2.0, 2.0, 2.0],
            {"actuator_offset": [0.0, 0.3, 0.0, 0.0], "actuator_gain": [-0.5, 0.0, 0.0, 0.2]},
            {"sensor_step": [2e-4, 0.0, 0.0, -1e-4]},
        ),
    ],
)
def test_faults_from_a_given_time_on_every_twin(kind, fs, u, actuator, sensor):
    """Paper 2 Sec. 4.4 on any rig: from t_start on, the applied input is (1 + gain)·u + offset per
    channel (before it, u itself), and a sensor step adds to the measurement of the same plant."""
    k0, ticks = 5, 12
    t_start = k0 / fs

    def drive(faults):
        rig = load_rig({"rig": {"kind": kind}, "faults": {"t_start": t_start, **faults} if faults else {}})
        ys = [rig.reset(1, [3], fs)[0]]
        applied = []
        for _ in range(ticks):
            ys.append(rig.step(np.array([u]))[0])
            applied.append(rig.applied_input[0].copy())
        return np.array(ys), np.array(applied)

    clean_y, clean_u = drive({})
    _, faulty_u = drive(actuator)
    np.testing.assert_array_equal(clean_u, np.tile(u, (ticks, 1)))
    gain = np.broadcast_to(actuator["actuator_gain"], len(u))
    offset = np.broadcast_to(actuator["actuator_offset"], len(u))
    np.testing.assert_array_equal(faulty_u[:k0], clean_u[:k0])
    np.testing.assert_allclose(faulty_u[k0:], np.tile((1 + gain) * np.array(u) + offset, (ticks - k0, 1)), rtol=1e-15)
    stepped_y, _ = drive(sensor)
    np.testing.assert_array_equal(stepped_y[:k0], clean_y[:k0])  # y[k] is the measurement at t = k/fs
    step = np.broadcast_to(sensor["sensor_step"], clean_y.shape[1])
    np.testing.assert_allclose(stepped_y[k0:] - clean_y[k0:], np.tile(step, (ticks + 1 - k0, 1)), rtol=1e-9, atol=1e-12)
