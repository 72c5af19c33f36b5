"""Bulk transfer: blocks through indexed frames, CRC and gap detection, retransmission until done."""

from __future__ import annotations

import random
import zlib

import pytest

from labrunner.rigs.transports import bulk


def test_block_layout_and_crc_are_zlib_crc32():
    block = bulk.Block(7, 0x1234, 5, bulk.FLAG_LAST, b"abc")
    raw = block.encode()
    assert raw[:10] == bytes([7, 0, 0, 0, 0x34, 0x12, 5, 1, 3, 0]) and raw[10:13] == b"abc"
    assert int.from_bytes(raw[13:], "little") == zlib.crc32(raw[:13])
    frames = block.frames(8)
    assert [f[0] for f in frames] == [0, 1, 2] and b"".join(f[1:] for f in frames) == raw


def test_max_body_fits_256_frames():
    assert bulk.max_body(8) == 256 * 7 - 14
    assert bulk.max_body(64) == 256 * 63 - 14
    with pytest.raises(ValueError):
        bulk.Block(0, 0, 1, 0, bytes(bulk.max_body(8) + 1)).frames(8)


def test_assembler_drops_corrupt_and_broken_blocks_and_ignores_fd_padding():
    counters = bulk.Counters()
    asm = bulk.Assembler(counters)
    good = bulk.Block(1, 9, 2, 0, bytes(range(40)))
    frames = good.frames(16)
    padded = frames[:-1] + [frames[-1] + b"\0" * 5]  # CAN FD rounds the last frame up
    out = [b for f in padded if (b := asm.feed(f))]
    assert out == [good]
    flipped = bytearray(frames[2])
    flipped[3] ^= 0x10
    assert [asm.feed(f) for f in frames[:2] + [bytes(flipped)] + frames[3:]][-1] is None
    assert counters.crc_errors == 1
    assert all(asm.feed(f) is None for f in frames[:1] + frames[2:])  # frame 1 lost
    assert counters.broken == 1
    assert [b for f in frames if (b := asm.feed(f))] == [good]  # and the next copy goes through


def _transfer(bodies, max_payload, drop, seed, window=8):
    """Send ``bodies`` over a lossy, corrupting frame channel; return what arrived and the ends."""
    rng = random.Random(seed)
    to_rx, to_tx = [], []
    tx = bulk.Sender(to_rx.append, max_payload, bulk.TO_HOST, 77, window=window, retry_s=0.05)
    rx = bulk.Receiver(to_tx.append, bulk.TO_HOST, transfer=77, window=window, nack_s=0.02)
    for i, body in enumerate(bodies):
        tx.queue(3, body, bulk.FLAG_LAST if i == len(bodies) - 1 else 0)
    got, now = [], 0.0
    while not tx.done:
        now += 0.01
        tx.pump(now)
        for frame in to_rx:
            if rng.random() < drop:
                continue
            if rng.random() < drop:
                b = bytearray(frame)
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
                frame = bytes(b)
            got += rx.feed(frame, now)
        to_rx.clear()
        rx.poll(now)
        for ack in to_tx:
            tx.on_ack(ack)
        to_tx.clear()
        assert now < 1000, "transfer does not finish"
    return got, tx, rx


@pytest.mark.parametrize("max_payload", [8, 64])
def test_lossy_link_delivers_every_block_once_in_order(max_payload):
    rng = random.Random(3)
    bodies = [rng.randbytes(rng.randrange(1, 3 * max_payload * 8)) for _ in range(60)]
    got, tx, rx = _transfer(bodies, max_payload, drop=0.01, seed=4)
    assert [b.body for b in got] == bodies and [b.seq for b in got] == list(range(60))
    c = rx.counters
    assert c.crc_errors + c.broken > 0 and c.nacks > 0 and tx.resent > 0


def test_clean_link_needs_no_resend():
    bodies = [bytes([i]) * 100 for i in range(20)]
    got, tx, rx = _transfer(bodies, 8, drop=0.0, seed=0)
    assert len(got) == 20 and tx.resent == 0 and rx.counters.nacks == 0 and rx.counters.crc_errors == 0


def test_acks_of_the_other_stream_or_transfer_are_ignored_and_cancel():
    tx = bulk.Sender(lambda f: None, 8, bulk.TO_DEVICE, 5)
    tx.queue(1, b"x")
    tx.on_ack(bulk.ACK.pack(bulk.ACK_OK | bulk.TO_HOST << 7, 8, 5, 1))
    tx.on_ack(bulk.ACK.pack(bulk.ACK_OK, 8, 6, 1))
    assert not tx.done
    tx.on_ack(bulk.ACK.pack(bulk.ACK_OK, 8, 5, 1))
    assert tx.done
    tx.on_ack(bulk.ACK.pack(bulk.CANCEL, 8, 5, 1))
    assert tx.cancelled


def test_a_late_copy_of_an_earlier_transfer_is_not_taken():
    acks = []
    done = {3}
    rx = bulk.Receiver(acks.append, bulk.TO_DEVICE, follow=lambda t: t not in done)
    late = bulk.Block(0, 3, 1, bulk.FLAG_LAST, b"old run")
    assert [b for f in late.frames(8) if (b := rx.feed(f, 0.0))] == [] and rx.counters.foreign == 1
    new = [bulk.Block(i, 4, 1, 0, bytes([i]) * 20) for i in range(3)]
    got = [b for blk in new for f in blk.frames(8) for b in rx.feed(f, 0.0)]
    assert got == new and rx.transfer == 4
    assert [b for f in late.frames(8) for b in rx.feed(f, 0.0)] == [] and rx.counters.foreign == 2
    assert bulk.ACK.unpack(acks[-1]) == (bulk.ACK_OK | bulk.TO_DEVICE << 7, 64, 4, 3)
