"""Real-rig transports: the frame protocol, a CAN rig and a serial rig against the firmware emulator."""

from __future__ import annotations

import random
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from labrunner.errors import InvalidParameter, RigError
from labrunner.rigs.base import RigConfig
from labrunner.rigs.config import config_from_dict, load_rig_config
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.emulator import Emulator, device_link, serve_on_pty, twin_for
from labrunner.rigs.transports.framing import SerialDecoder, crc16, encode_frame
from labrunner.rigs.transports.messages import DeviceState, ErrorCode
from labrunner.rigs.transports.protocol import End, Frame, Kind, can_id, senders, split_can_id

MODEL = {"static_friction": 0.0, "coulomb_friction": 0.0, "backlash": 0.0, "electrical_tau": 0.0}
U = 6.0 * np.sin(np.arange(60) / 8.0)


# -- protocol -----------------------------------------------------------------------------------
def _crc16_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE by its definition: polynomial 0x1021, initial 0xFFFF, MSB first, no final XOR."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc16_check_value():
    assert crc16(b"123456789") == 0x29B1  # CRC-16/CCITT-FALSE catalogue check value


def test_crc16_is_the_bitwise_definition_on_every_frame_size():
    rng = np.random.default_rng(7)
    for n in [0, 1, 2, *range(3, 70)]:  # every body a serial frame can carry (node, code, ≤ 64 B, CRC)
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert crc16(data) == _crc16_bitwise(data), n
    assert crc16(b"\x00" * 66) == _crc16_bitwise(b"\x00" * 66) and crc16(b"\xff" * 66) == _crc16_bitwise(b"\xff" * 66)


def test_can_ids_are_legal_and_safety_first():
    every = [can_id(n, kind, end) for kind in Kind for end in senders(kind) for n in (1, 127)]
    assert min(every) > 0 and max(every) < 0x7F0 and len(set(every)) == len(every)
    for kind in Kind:
        for end in End:
            try:
                ident = can_id(9, kind, end)
            except ValueError:
                continue
            assert split_can_id(ident) == (9, kind, end)
    safety = max(
        can_id(127, k, End.HOST if k != Kind.ERROR else End.DEVICE) for k in (Kind.SAFE, Kind.STOP, Kind.ERROR)
    )
    assert safety < can_id(1, Kind.INPUT, End.HOST)  # any node's safety frame beats every data frame
    for bad in (0, 128):
        with pytest.raises(ValueError):
            can_id(bad, Kind.SAFE, End.HOST)


def test_serial_decoder_resyncs_on_garbage_and_split_reads():
    frames = [m.pack(m.Measurement(k, 0, 0, 0.5 * k)) for k in range(5)]
    encoded = [encode_frame(2, int(f.kind), f.payload) for f in frames]
    corrupt = bytearray(encode_frame(2, int(Kind.INPUT), bytes(8)))
    corrupt[5] ^= 0xFF
    stream = b"\x13\x07garbage" + encoded[0] + bytes(corrupt) + b"".join(encoded[1:])
    decoder = SerialDecoder()
    got = []
    for i in range(0, len(stream), 5):
        got += decoder.feed(stream[i : i + 5])
    assert [payload for node, code, payload in got] == [f.payload for f in frames]
    assert decoder.counters.crc_errors + decoder.counters.malformed >= 2 and decoder.counters.garbage_bytes > 9


# -- a CAN rig against the emulator ---------------------------------------------------------------
def can_config(interface: str, timeout_s: float = 0.2, device: str = "dcmotor", **parameters) -> RigConfig:
    """A host-loop CAN rig file of ``device`` on a fresh bus (the motor: frictionless model)."""
    channel = "239.74.163.2" if interface == "udp_multicast" else f"labrunner-{uuid.uuid4().hex}"
    port = random.randint(20000, 60000) if interface == "udp_multicast" else 0
    motor = device == "dcmotor"
    return config_from_dict(
        {
            "rig": {"kind": "can", "name": f"{device}-can"},
            "parameters": {
                "device": device,
                "interface": interface,
                "channel": channel,
                "loop": "host",
                "port": port,
                "node_id": 7,
                "timeout_s": timeout_s,
                "model": MODEL if motor else {},
                **parameters,
            },
            "safety": {"max_du_dt": 120.0} if motor else {},
        }
    )


@pytest.fixture(params=["udp_multicast", "virtual"])
def can_pair(request):
    """(host rig, emulator) on one python-can bus; multicast on loopback, and python-can's virtual bus."""
    config = can_config(request.param)
    emulator = Emulator(twin_for(config), device_link(config), paced=False).start()
    rig = load_rig(config)
    yield rig, emulator
    rig.close()
    emulator.stop()


def direct_run(u: np.ndarray, seed: int) -> np.ndarray:
    twin = twin_for(can_config("virtual"))
    ys = [twin.reset(1, [seed], 200.0)[0, 0]] + [twin.step(np.array([[v]]))[0, 0] for v in u]
    return np.array(ys)


def host_run(rig, u: np.ndarray, seed: int) -> np.ndarray:
    ys = [rig.reset(1, [seed], 200.0)[0, 0]] + [rig.step(np.array([[v]]))[0, 0] for v in u]
    return np.array(ys)


def test_can_rig_serves_the_twin(can_pair):
    rig, emulator = can_pair
    assert rig.info.kind == "dcmotor" and not rig.info.simulated and rig.info.constants["b"] == 108.55
    np.testing.assert_allclose(host_run(rig, U, 3), direct_run(U, 3), rtol=1e-6, atol=1e-6)  # float32 frames
    np.testing.assert_allclose(host_run(rig, U, 4), direct_run(U, 4), rtol=1e-6, atol=1e-6)  # a second run
    assert not emulator.errors and emulator.last_error in (ErrorCode.NONE, ErrorCode.WATCHDOG)  # idle host: watchdog


def test_can_rig_is_batch_one_only(can_pair):
    rig, _ = can_pair
    with pytest.raises(InvalidParameter, match="batch"):
        rig.reset(2, [0, 1], 200.0)
    with pytest.raises(InvalidParameter, match="overrides.a"):
        rig.reset(1, [0], 200.0, {"a": 1.0})


def wait_for(predicate, timeout=2.0):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)
    return predicate()


def test_safe_state_command_reaches_the_device(can_pair):
    rig, emulator = can_pair
    rig.reset(1, [0], 200.0)
    rig.step(np.array([[5.0]]))
    rig.safe_state()
    assert wait_for(lambda: emulator.state == DeviceState.SAFE)
    assert emulator.rig.is_safe.all()


def test_device_fault_raises_rig_error_and_goes_safe(can_pair):
    rig, emulator = can_pair
    rig.reset(1, [0], 200.0)
    emulator.inject_fault(ErrorCode.DEVICE_FAULT)
    with pytest.raises(RigError, match="DEVICE_FAULT"):
        rig.step(np.array([[3.0]]))
    assert rig.is_safe.all() and emulator.state == DeviceState.SAFE


def test_device_gone_times_out_into_the_safe_state(can_pair):
    rig, emulator = can_pair
    rig.reset(1, [0], 200.0)
    emulator.stop()
    t0 = time.monotonic()
    with pytest.raises(RigError, match="no complete measurement"):
        rig.step(np.array([[3.0]]))
    assert time.monotonic() - t0 < 1.0 and rig.is_safe.all()


def test_watchdog_trips_when_the_host_falls_silent():
    config = can_config("virtual")
    with Emulator(twin_for(config), device_link(config), paced=False) as emulator:
        rig = load_rig(config)
        rig.reset(1, [0], 200.0)  # watchdog_periods = 10 at 200 Hz: 50 ms
        assert wait_for(lambda: emulator.state == DeviceState.SAFE)
        with pytest.raises(RigError, match="WATCHDOG"):
            rig.step(np.array([[1.0]]))
        rig.close()


def test_unopenable_bus_is_a_rig_error():
    config = can_config("virtual")
    bad = config_from_dict(
        {
            **config.to_dict(),
            "rig": {"kind": "can"},
            "parameters": {**config.parameters, "interface": "no-such-interface"},
        }
    )
    with pytest.raises(RigError, match="cannot open CAN bus"):
        load_rig(bad)


# -- a serial rig over a pty pair -----------------------------------------------------------------
def serial_config(port: str) -> dict:
    return config_from_dict(
        {
            "rig": {"kind": "serial", "name": "motor-serial"},
            "parameters": {
                "device": "dcmotor",
                "port": port,
                "baudrate": 115200,
                "node_id": 1,
                "timeout_s": 0.2,
                "model": MODEL,
            },
        }
    )


def test_serial_rig_over_a_pty_pair():
    twin = twin_for(serial_config("unused"))
    name, emulator = serve_on_pty(twin, paced=False)
    try:
        rig = load_rig(serial_config(name))
        np.testing.assert_allclose(host_run(rig, U, 5), direct_run(U, 5), rtol=1e-6, atol=1e-6)
        emulator.stop()
        with pytest.raises(RigError):
            rig.step(np.array([[1.0]]))
        assert rig.is_safe.all()
        rig.close()
    finally:
        emulator.stop(close_link=False)


def test_missing_serial_port_is_a_rig_error(tmp_path):
    with pytest.raises(RigError, match="cannot open serial port"):
        load_rig(serial_config(str(tmp_path / "ttyNONE")))


def test_remote_rig_files_reject_noise_and_bad_model_keys():
    base = {"rig": {"kind": "can"}, "parameters": {"device": "valve", "model": {"a": 1.0}}}
    with pytest.raises(InvalidParameter) as err:
        config_from_dict(base)
    assert err.value.field == "<dict>: parameters.model.a"
    with pytest.raises(InvalidParameter) as err:
        config_from_dict({"rig": {"kind": "serial"}, "noise": {"input_v": 0.1}})
    assert err.value.field == "<dict>: noise.input_v"


# -- Link v1: raw payloads ------------------------------------------------------------------------
@pytest.mark.parametrize("interface", ["udp_multicast", "virtual"])
def test_can_fd_links_carry_bulk_payloads_padded_to_a_valid_length(interface):
    from labrunner.rigs.transports.can import CanLink

    p = can_config(interface, fd=True).parameters
    host, device = CanLink.open(p, End.HOST), CanLink.open(p, End.DEVICE)
    try:
        assert host.max_payload == 64
        host.send(Frame(Kind.BULK_TO_DEVICE, bytes(range(1, 14))))
        got = device.recv(1.0)
        assert got.kind == Kind.BULK_TO_DEVICE and got.payload == bytes(range(1, 14)) + bytes(3)  # DLC 16
        device.send(Frame(Kind.BULK_ACK, b"\x07"))
        assert host.recv(1.0) == Frame(Kind.BULK_ACK, b"\x07")  # the device's own BULK_ACK code
        with pytest.raises(ValueError, match="max_payload 64"):
            host.send(Frame(Kind.BULK_TO_DEVICE, bytes(65)))
        with pytest.raises(ValueError, match="does not send BULK_TO_HOST"):
            host.send(Frame(Kind.BULK_TO_HOST, bytes(8)))
        with pytest.raises(ValueError):
            host.send(Frame(Kind.INPUT, bytes(7)))  # fixed messages are 8 bytes on every link
    finally:
        host.close()
        device.close()


def test_a_host_loop_runs_over_can_fd():
    config = can_config("udp_multicast", fd=True)
    with Emulator(twin_for(config), device_link(config), paced=False) as emulator:
        rig = load_rig(config)
        np.testing.assert_allclose(host_run(rig, U, 3), direct_run(U, 3), rtol=1e-6, atol=1e-6)
        assert emulator.identity().capabilities & m.Capability.CAN_FD
        rig.close()


def test_rig_files_name_legal_node_ids_and_a_loop_placement():
    base = {"rig": {"kind": "can"}, "parameters": {"device": "dcmotor", "interface": "virtual", "channel": "x"}}
    for node in (0, 128):
        with pytest.raises(InvalidParameter) as err:
            config_from_dict({**base, "parameters": {**base["parameters"], "node_id": node}})
        assert err.value.field.endswith("parameters.node_id") and "[1, 127]" in str(err.value)
    with pytest.raises(InvalidParameter, match="parameters.loop"):
        config_from_dict({**base, "parameters": {**base["parameters"], "loop": "both"}})
    defaults = {
        d: config_from_dict({**base, "parameters": {**base["parameters"], "device": d}}).parameters["loop"]
        for d in ("dcmotor", "valve", "plate")
    }
    assert defaults == {"dcmotor": "host", "valve": "device", "plate": "device"}
    rigs = Path(__file__).resolve().parents[1] / "rigs"
    shipped = {
        p.name: load_rig_config(p).parameters["loop"] for p in [*rigs.glob("*-can.toml"), *rigs.glob("*-serial.toml")]
    }
    assert shipped == {
        f"{d}-{t}.toml": "host" if d == "dcmotor" else "device"
        for d in ("dcmotor", "valve", "plate")
        for t in ("can", "serial")
    }
