"""Link-load model: frame lengths against published worst cases, loads of the thesis's rigs."""

from __future__ import annotations

import pytest

from labrunner.rigs.transports import linkload as ll

CAN_1M = ll.LinkSpec("can", 1_000_000)


def test_classic_can_worst_case_frame_lengths():
    # Davis, Burns, Bril, Lukkien (2007): 11-bit identifiers, C = 55 + 10 s bit times for s ≤ 8 bytes
    for n in range(9):
        assert ll.can_frame_bits(n) == 47 + 8 * n + (33 + 8 * n) // 4 <= 55 + 10 * n
    assert ll.can_frame_bits(8) == 135 and ll.can_frame_bits(0) == 55
    with pytest.raises(ValueError):
        ll.can_frame_bits(9)


def test_serial_frame_is_ten_bits_per_byte():
    link = ll.LinkSpec("serial", 115_200, max_payload=64)
    assert link.frame_s(8) == pytest.approx(150 / 115_200)  # 8 + 7 framing bytes, 8N1


def test_canfd_lengths_round_up_and_the_data_phase_runs_faster():
    assert [ll.fd_length(n) for n in (0, 8, 9, 13, 33, 64)] == [0, 8, 12, 16, 48, 64]
    nominal, data = ll.canfd_frame_bits(64)
    assert nominal == 34 and data > 8 * 64  # 512 data bits plus stuffing, DLC, CRC-21
    slow = ll.LinkSpec("canfd", 1e6, 1e6, 64).frame_s(64)
    fast = ll.LinkSpec("canfd", 1e6, 5e6, 64).frame_s(64)
    assert fast < slow / 3
    with pytest.raises(ValueError):
        ll.fd_length(65)


def test_host_loop_loads_of_protocol_v1():
    # one 8-byte frame per input host → device, per output and the tick trailer device → host:
    # the valve (i → q) at 4 kHz needs 162 % of 1 Mbit/s worst case (4000 × 3 × 135 bits), the
    # plate (4 currents in, 3 gaps + trailer out) at 32 kHz over 34 buses (the twin has a fourth sensor)
    assert ll.host_loop_load(CAN_1M, 4000, 1, 1) == pytest.approx(1.62)
    assert ll.host_loop_load(CAN_1M, 32000, 4, 3) == pytest.approx(32000 * 8 * 135 / 1e6)
    assert ll.host_loop_load(CAN_1M, 200, 1, 1) == pytest.approx(200 * 3 * 135 / 1e6)
    assert ll.max_host_fs(CAN_1M, 1, 1) == pytest.approx(0.8e6 / 405)


def test_serial_is_full_duplex():
    link = ll.LinkSpec("serial", 1_000_000, max_payload=64)
    # the busier way: 3 measurements + trailer of 8 + 7 framing bytes, 150 bits each
    assert ll.host_loop_load(link, 1000, 1, 3) == pytest.approx(1000 * 4 * 150 / 1e6)


def test_refusal_names_the_load_and_the_alternative():
    msg = ll.check_host_loop(CAN_1M, 32000, 4, 3)
    assert "3456%" in msg and 'loop = "device"' in msg and "classic CAN at 1 Mbit/s" in msg
    assert "741 Hz" in msg  # 0.8 Mbit/s / (8 × 135 bits)
    assert ll.check_host_loop(CAN_1M, 200, 1, 1) == ""


def test_rig_parameters_name_the_link():
    assert ll.from_rig("can", {"bitrate": 500_000, "fd": False}) == ll.LinkSpec("can", 500_000)
    fd = ll.from_rig("can", {"bitrate": 1_000_000, "fd": True, "data_bitrate": 5_000_000})
    assert fd.medium == "canfd" and fd.max_payload == 64
    assert ll.from_rig("serial", {"baudrate": 921_600}).bitrate == 921_600


def test_device_loop_streams_only_what_fits():
    motor = ll.report(CAN_1M, 200, 1, 1, 6, duration=5.0)
    assert motor.device_streams and motor.host_feasible
    plate = ll.report(ll.LinkSpec("canfd", 1e6, 5e6, 64), 32000, 4, 3, 20, duration=3.0)
    assert not plate.host_feasible and not plate.device_streams
    # 3 s × 32 kHz × 20 float32 ≈ 7.7 MB in 63-byte frames of ≈ 0.17 ms each
    assert 15.0 < plate.upload_s < 30.0
