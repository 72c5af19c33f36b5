"""rigs/labrunner.dbc against the protocol code, read by cantools (what candump/SavvyCAN users load).

Every message kind is packed by :mod:`labrunner.rigs.transports.messages` and decoded by cantools,
and encoded by cantools and unpacked by the protocol code; identifiers come from
:func:`~labrunner.rigs.transports.protocol.can_id` for node 1, the node the DBC describes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.protocol import BULK_KINDS, End, Frame, Kind, can_id, senders

cantools = pytest.importorskip("cantools")
DBC = Path(__file__).resolve().parents[1] / "rigs" / "labrunner.dbc"
F32 = 1.5  # exact in float32

# one instance per fixed message, with the DBC signal names of its fields
CASES = [
    (m.Safe(513), {"seq": 513}),
    (m.Stop(7), {"seq": 7}),
    (m.Error(int(m.ErrorCode.WATCHDOG), 999, -F32), {"code": "WATCHDOG", "seq": 999, "detail": -F32}),
    (m.Input(65535, 3, m.FLAG_COMMIT, F32), {"seq": 65535, "channel": 3, "flags": 1, "value": F32}),
    (m.Measurement(12, 2, 0, -2 * F32), {"seq": 12, "channel": 2, "flags": 0, "value": -2 * F32}),
    (
        m.TickEnd(12, m.TICK_CHANNEL, m.FLAG_LATE | m.FLAG_OVERRUN, 4_000_000_000),
        {"seq": 12, "channel": 255, "flags": 3, "timestamp_us": 4_000_000_000},
    ),
    (m.Heartbeat(2**32 - 1), {"counter": 2**32 - 1}),
    (
        m.Status(int(m.DeviceState.SAFE), int(m.ErrorCode.SEQUENCE), 40000, 17, 300),
        {"state": "SAFE", "last_error": 5, "rejected": 40000, "late": 17, "seq": 300},
    ),
    (m.Hello(1), {"version": 1}),
]


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_file(str(DBC))


def frame_id(frame: Frame) -> int:
    (sender,) = senders(frame.kind)
    return can_id(1, frame.kind, sender)


@pytest.mark.parametrize("message, signals", CASES, ids=[type(c[0]).__name__ for c in CASES])
def test_fixed_messages_round_trip_through_cantools(db, message, signals):
    frame = m.pack(message)
    decoded = db.decode_message(frame_id(frame), frame.payload)
    assert {k: (str(v) if hasattr(v, "name") else v) for k, v in decoded.items()} == signals
    encoded = db.get_message_by_frame_id(frame_id(frame)).encode(signals)  # choice names encode too
    assert m.unpack(Frame(frame.kind, encoded)) == message


def test_setup_and_identity_records(db):
    frames = m.setup_frames(200.0, 0.015, 123456)
    decoded = [db.decode_message(frame_id(f), f.payload) for f in frames]
    assert [d["index"] for d in decoded] == [0, 1, 2]
    assert decoded[0]["fs"] == 200.0 and decoded[1]["watchdog"] == pytest.approx(0.015, rel=1e-7)
    assert decoded[2]["seed"] == 123456
    ident = m.Identity(
        1, int(m.DeviceKind.PLATE), 4, 4, int(m.Capability.HOST_LOOP | m.Capability.DEVICE_LOOP), 32000.0, 0xDEADBEEF
    )
    records = {}
    for f in m.identity_frames(ident):
        d = db.decode_message(frame_id(f), f.payload, decode_choices=False)
        records[d["index"]] = d
        # cantools' own encoding of the record equals the protocol's
        assert db.get_message_by_name("IDENTITY").encode(d) == f.payload
    assert records[0] == {"index": 0, "version": 1, "device_kind": 3, "n_inputs": 4, "n_outputs": 4}
    assert records[1]["capabilities"] == 3 and records[2]["max_fs"] == 32000.0
    assert records[3]["firmware_id"] == 0xDEADBEEF
    assert m.identity_from({i: m.unpack(f).value for i, f in enumerate(m.identity_frames(ident))}) == ident


def test_every_kind_has_its_identifier_and_size_in_the_dbc(db):
    by_id = {msg.frame_id: msg for msg in db.messages}
    for kind in Kind:
        for sender in senders(kind):
            msg = by_id[can_id(1, kind, sender)]
            assert msg.length == 8 and msg.name.startswith(kind.name)
            assert msg.senders == [sender.name]
            if kind in BULK_KINDS:  # raw bytes, in order
                payload = bytes(range(10, 18))
                assert db.decode_message(msg.frame_id, payload) == {f"b{i}": 10 + i for i in range(8)}
    assert len(db.messages) == sum(len(senders(k)) for k in Kind)


def test_float_fields_are_ieee754_little_endian(db):
    payload = struct.pack("<HBBf", 1, 0, 0, 3.25)
    assert db.decode_message(can_id(1, Kind.INPUT, End.HOST), payload)["value"] == 3.25
    assert m.unpack(Frame(Kind.INPUT, payload)).value == 3.25
