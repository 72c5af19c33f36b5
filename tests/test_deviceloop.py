"""Device loop without a link: the run description, the firmware's reference executor and both
session ends over an in-process lossy channel, each against the twin engine's run of the point."""

from __future__ import annotations

import queue
import random
import threading
import time
import zlib

import numpy as np
import pytest

from labrunner.errors import InvalidParameter, RigError
from labrunner.rigs.device import blocks, description, executor, host, session
from labrunner.rigs.device.columns import to_columns
from labrunner.rigs.device.description import DescriptionError
from labrunner.rigs.registry import load_rig
from labrunner.rigs.transports import bulk, linkload
from tests.deviceloop_points import POINTS, assert_same_as_twin, twin_run


@pytest.mark.parametrize("name", sorted(POINTS))
def test_description_round_trip(name):
    point, rig_name, fs, duration, safety = POINTS[name]
    rig = load_rig(rig_name)
    data = description.build(point, rig.info, fs=fs, duration=duration, seed=7, rig_safety=safety, watchdog_s=0.02)
    d = description.decode(data)
    assert (d.fs, d.duration, d.ticks, d.seed, d.watchdog_s, d.kind) == (
        fs,
        duration,
        round(fs * duration),
        7,
        0.02,
        point["controller"]["kind"],
    )
    # the point comes back as it went (numbers as numbers, lists as lists, bounds as tables)
    for section in ("controller", "differentiator", "reference", "safety"):
        assert d.point()[section] == dict(point.get(section, {}))
    assert description.rig_safety(d) == dict(safety)
    assert int.from_bytes(data[-4:], "little") == zlib.crc32(data[:-4])


def test_description_refuses_a_flipped_bit_and_another_version():
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    data = bytearray(
        description.build(point, load_rig(rig_name).info, fs=fs, duration=duration, seed=0, rig_safety=safety)
    )
    rng = random.Random(0)
    for _ in range(20):
        bad = bytearray(data)
        bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
        with pytest.raises(DescriptionError):
            description.decode(bytes(bad))
    other = bytearray(data)
    other[4] = 2
    other[-4:] = zlib.crc32(bytes(other[:-4])).to_bytes(4, "little")
    with pytest.raises(DescriptionError, match="version 2"):
        description.decode(bytes(other))


def test_what_cannot_be_expressed_is_refused_with_the_field():
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    info = load_rig(rig_name).info
    with pytest.raises(InvalidParameter, match="rig_parameters"):
        description.build({**point, "rig_parameters": {"a": 40.0}}, info, fs=fs, duration=duration, seed=0)
    with pytest.raises(InvalidParameter, match=r"campaign\.duration"):
        description.build(point, info, fs=fs, duration=0.0, seed=0)
    with pytest.raises(InvalidParameter, match=r"controller\.k_p"):  # the engine's own checks run first
        description.build(
            {**point, "controller": {**point["controller"], "k_p": "fast"}}, info, fs=fs, duration=duration, seed=0
        )


def test_executor_refuses_records_that_disagree_with_the_point():
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    rig = load_rig(rig_name)
    data = description.build(point, rig.info, fs=fs, duration=duration, seed=0, rig_safety=safety)
    d = description.decode(data)
    key = (description.FIR_CONTROLLER, 1)
    tampered = {**d.fir, key: d.fir[key] * (1 + 1e-12)}
    with pytest.raises(DescriptionError, match="FIR weights"):
        executor.check(description.Description(**{**d.__dict__, "fir": tampered}), rig)
    with pytest.raises(DescriptionError, match="reference segments"):
        executor.check(description.Description(**{**d.__dict__, "trajectories": d.trajectories[:0]}), rig)
    with pytest.raises(DescriptionError, match="outputs"):
        executor.check(d, _plate())
    point, _, fs, duration, safety = POINTS["plate-mfc"]
    plate = description.decode(
        description.build(point, _plate().info, fs=fs, duration=duration, seed=0, rig_safety=safety)
    )
    notch = {"_notch": plate.filters["_notch"] * 1.001}
    with pytest.raises(DescriptionError, match="filter matrices"):
        executor.check(description.Description(**{**plate.__dict__, "filters": notch}), _plate())


def _plate():
    return load_rig("plate-sim")


@pytest.mark.parametrize("name", sorted(POINTS))
def test_executor_equals_the_twin_engine(name):
    point, rig_name, fs, duration, safety = POINTS[name]
    rig = load_rig(rig_name)
    data = description.build(point, rig.info, fs=fs, duration=duration, seed=11, rig_safety=safety)
    run = executor.execute(data, rig)
    twin = twin_run(name, seed=11)
    assert run.verdict.status == twin.outcome.status and run.verdict.n_samples == twin.n_samples
    assert np.array_equal(run.columns, to_columns(twin.signals, twin.channels))  # bit for bit in float32


@pytest.mark.parametrize("name", ["motor-mfc2", "motor-open-loop", "plate-mfc"])
def test_a_reference_sent_as_a_sample_table_runs_as_the_twin(name):
    """reference_table: every output's reference travels as its samples; the device runs the
    table by tick index and its run equals the twin's bit for bit in float32."""
    point, rig_name, fs, duration, safety = POINTS[name]
    rig = load_rig(rig_name)
    data = description.build(
        point, rig.info, fs=fs, duration=duration, seed=11, rig_safety=safety, reference_table=True
    )
    d = description.decode(data)
    assert {code for code, _ in d.trajectories} == {description.T_TABLE}
    twin = twin_run(name, seed=11)
    for j, (_, (head, flat)) in enumerate(d.trajectories):  # a hand check: row k is the reference at k/f_s
        rows = flat.reshape(-1, 4)
        assert head.tolist() == [fs] and 1 < len(rows) <= d.ticks
        ref = twin.signals[twin.channels["references"][j]]
        k = np.minimum(np.arange(len(ref)), len(rows) - 1)
        assert np.array_equal(rows[k, 0], ref)  # the held last row is the reference to the end
    run = executor.execute(data, rig)
    assert np.array_equal(run.columns, to_columns(twin.signals, twin.channels))
    tampered = [(code, [head, flat + 1e-9]) for code, (head, flat) in d.trajectories]
    with pytest.raises(DescriptionError, match="reference segments"):
        executor.check(description.Description(**{**d.__dict__, "trajectories": tampered}), rig)


class _Channel:
    """Two queues between host and device; bulk frames the device sends (of ``kinds``) are dropped
    or corrupted with probability ``fault``."""

    def __init__(self, fault: float, seed: int, kinds: tuple[str, ...] = (session.TO_HOST,)) -> None:
        self.q = {"host": queue.Queue(), "device": queue.Queue()}
        self.rng, self.fault, self.kinds = random.Random(seed), fault, kinds

    def end(self, me: str, other: str):
        def send(kind, payload):
            if me == "device" and kind in self.kinds and self.rng.random() < self.fault:
                if self.rng.random() < 0.5:
                    return
                b = bytearray(payload)
                b[-1] ^= 0x21
                payload = bytes(b)
            self.q[other].put((kind, payload))

        def recv(timeout):
            try:
                return self.q[me].get(timeout=timeout) if timeout > 0 else self.q[me].get_nowait()
            except queue.Empty:
                return None

        return send, recv


def _serve(channel: _Channel, rig, stop: threading.Event):
    send, recv = channel.end("device", "host")
    dev = session.DeviceSession(send, recv, 8, lambda data, **kw: executor.execute(data, rig, **kw))
    while not stop.is_set():
        if (msg := recv(0.01)) is not None:
            dev.on_message(*msg)


@pytest.mark.parametrize(
    "name, stream", [("motor-mfc2", False), ("motor-mfc2", True), ("motor-aborted", True), ("valve-mfc1", False)]
)
def test_session_over_a_lossy_channel_gives_the_twin_result(name, stream):
    point, rig_name, fs, duration, safety = POINTS[name]
    channel, stop = _Channel(fault=0.003, seed=5), threading.Event()
    device = threading.Thread(target=_serve, args=(channel, load_rig(rig_name), stop), daemon=True)
    device.start()
    try:
        send, recv = channel.end("host", "device")
        link = linkload.LinkSpec("can", 1e6) if stream else None  # 200 Hz × 6 columns fit: stream
        [result] = host.run(
            send,
            recv,
            8,
            [point],
            load_rig(rig_name).info,
            fs=fs,
            duration=duration,
            seeds=[11],
            rig_safety=safety,
            link=link,
        )
    finally:
        stop.set()
        device.join()
    assert_same_as_twin(result, name, 11)
    twin = twin_run(name, seed=11)
    d = result.diagnostics
    assert d["streamed"] is stream and d["ticks"] == twin.n_samples and d["overruns"] == 0
    assert (
        d["received"]["crc_errors"] + d["received"]["broken"] > 0 and d["received"]["nacks"] > 0
    )  # faults were healed


def test_lost_device_acks_never_run_a_description_twice():
    """The device's ACKs of the description are lost: the host resends it while the device runs,
    and again later; the device runs it once (its transfer is done) and the host gets its result."""
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    rig = load_rig(rig_name)
    channel, stop = _Channel(fault=1.0, seed=0, kinds=(session.ACK,)), threading.Event()
    runs = []

    def serve():
        send, recv = channel.end("device", "host")
        dev = session.DeviceSession(
            send, recv, 8, lambda data, **kw: runs.append(1) or executor.execute(data, rig, **kw)
        )
        while not stop.is_set():
            if (msg := recv(0.01)) is not None:
                dev.on_message(*msg)

    device = threading.Thread(target=serve, daemon=True)
    device.start()
    try:
        send, recv = channel.end("host", "device")
        [result] = host.run(send, recv, 8, [point], rig.info, fs=fs, duration=duration, seeds=[11], rig_safety=safety)
        time.sleep(1.2)  # past the host's resend timer: nothing may start another run
    finally:
        stop.set()
        device.join()
    assert runs == [1]
    assert_same_as_twin(result, "motor-mfc1", 11)


def test_a_refused_description_raises_on_the_host():
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    channel, stop = _Channel(fault=0.0, seed=0), threading.Event()
    device = threading.Thread(target=_serve, args=(channel, _plate(), stop), daemon=True)  # the wrong device
    device.start()
    try:
        send, recv = channel.end("host", "device")
        data = description.build(point, load_rig(rig_name).info, fs=fs, duration=duration, seed=0, rig_safety=safety)
        with pytest.raises(RigError, match="refused the run: description for 1 inputs"):
            session.run_on_device(send, recv, 8, data, 10, 6, fs)
    finally:
        stop.set()
        device.join()


def test_a_silent_device_raises_within_dead_s_and_says_the_rig_may_not_be_safe():
    t0 = time.monotonic()
    with pytest.raises(
        session.RunFailed, match="no frame from the device for 0.3 s.*may not be in its safe state"
    ) as exc:
        session.run_on_device(lambda k, p: None, lambda t: None, 8, b"x" * 20, 10, 6, 200.0, dead_s=0.3)
    assert 0.3 <= time.monotonic() - t0 < 1.0 and len(exc.value.rows) == 0


def test_verdict_round_trip():
    v = blocks.Verdict("aborted", 10, 10, 2, "du_dt", 0.05, 130.0, 120.0, "", 50_000, 123)
    assert blocks.Verdict.decode(v.encode()) == v


def _device_thread(rig):
    """A device session on a fresh channel in a thread; returns (channel, session holder, stop event, thread)."""
    channel, stop, held = _Channel(fault=0.0, seed=0), threading.Event(), {}

    def serve():
        send, recv = channel.end("device", "host")
        held["session"] = dev = session.DeviceSession(
            send, recv, 8, lambda data, **kw: executor.execute(data, rig, **kw)
        )
        held["runs"] = runs = []
        original = dev.execute

        def recording(data, **kw):
            run = original(data, **kw)
            runs.append(run)
            return run

        dev.execute = recording
        while not stop.is_set():
            if (msg := recv(0.01)) is not None:
                dev.on_message(*msg)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return channel, held, stop, thread


def _send_description(send, data: bytes, transfer: int = 0) -> None:
    """The description's blocks, sent once and never acknowledged or resent."""
    sender = bulk.Sender(lambda p: send(session.TO_DEVICE, p), 8, bulk.TO_DEVICE, transfer)
    parts = session._slices(data, sender.body_limit)
    for i, part in enumerate(parts):
        sender.queue(blocks.DESCRIPTION, part, bulk.FLAG_LAST if i == len(parts) - 1 else 0)
    sender.pump(0.0)


def test_stop_from_the_host_ends_the_run_failed_and_safe():
    point, rig_name, fs, _, safety = POINTS["valve-mfc1"]
    rig = load_rig(rig_name)
    channel, held, stop, thread = _device_thread(rig)
    try:
        send, recv = channel.end("host", "device")
        # a watchdog far longer than the test's wait: this host sends no heartbeats, and the STOP is what ends the run
        data = description.build(point, rig.info, fs=fs, duration=20.0, seed=0, rig_safety=safety, watchdog_s=30.0)
        _send_description(send, data)
        assert _wait(lambda: (msg := recv(0.05)) is not None and msg[0] == session.TO_HOST)  # the run began
        send(session.STOP, b"")  # what the emulator's adapter hands over for SAFE or STOP
        assert _wait(lambda: held.get("runs"))
    finally:
        stop.set()
        thread.join()
    run = held["runs"][0]
    assert run.verdict.status == "failed" and "stopped by the host" in run.verdict.message
    assert run.verdict.n_samples < 20.0 * fs and rig.is_safe.all()


def test_a_silent_host_trips_the_device_watchdog():
    point, rig_name, fs, _, safety = POINTS["valve-mfc1"]
    rig = load_rig(rig_name)
    channel, held, stop, thread = _device_thread(rig)
    try:
        send, _ = channel.end("host", "device")
        data = description.build(point, rig.info, fs=fs, duration=20.0, seed=0, rig_safety=safety, watchdog_s=0.3)
        _send_description(send, data)  # then silence: no ACKs, no heartbeats
        assert _wait(lambda: held.get("runs"), 30.0)
    finally:
        stop.set()
        thread.join()
    run = held["runs"][0]
    assert run.verdict.status == "failed" and "watchdog" in run.verdict.message and rig.is_safe.all()
    assert run.verdict.n_samples < 20.0 * fs


def test_the_next_description_ends_an_upload_whose_last_acks_were_lost():
    """The host holds a run's verdict but its final ACKs were lost: the device is still resending
    that run's results when the next description arrives. It must take the new run at once
    instead of ignoring it until its upload times out (the host's own silence limit is as long,
    so a campaign's second run failed "no new block … during the description")."""
    point, rig_name, fs, _, safety = POINTS["motor-mfc1"]
    rig = load_rig(rig_name)
    channel, held, stop, thread = _device_thread(rig)
    try:
        send, _ = channel.end("host", "device")
        data = description.build(point, rig.info, fs=fs, duration=1.0, seed=0, rig_safety=safety, watchdog_s=30.0)
        _send_description(send, data, transfer=1)  # its results are never acknowledged
        assert _wait(lambda: len(held.get("runs", ())) == 1)
        t0 = time.monotonic()
        _send_description(send, data, transfer=2)
        assert _wait(lambda: len(held["runs"]) == 2, timeout=3.0), "the device ignored the next description"
        assert time.monotonic() - t0 < held["session"].upload_silence_s / 2
        assert held["session"].tx.transfer == 2  # the second run's results go out under its transfer
    finally:
        stop.set()
        thread.join()


def _wait(predicate, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)
    return predicate()


def test_filter_records_step_like_the_controllers_filters():
    """The plate MBC's FILTER record, run as firmware would ([out, x⁺] = [x, w] · M), gives the
    controller's own filter outputs for a random input sequence."""
    from labrunner.control import factory

    point, rig_name, fs, duration, safety = POINTS["plate-mbc"]
    info = load_rig(rig_name).info
    d = description.decode(description.build(point, info, fs=fs, duration=duration, seed=0, rig_safety=safety))
    controller, _ = factory.build([point], info, fs)
    chain = controller._chain
    M = d.filters["_chain"]
    n, m = chain.n, chain.m
    rng = np.random.default_rng(0)
    w = rng.normal(size=(50, 3, m))
    chain.reset(np.zeros((1, 3, m)))
    x = np.zeros((3, n))
    for k in range(50):
        out, x = np.split(np.hstack([x, w[k]]) @ M, [chain.p], axis=1)
        np.testing.assert_allclose(chain.step(w[k][None])[0], out, rtol=1e-12, atol=1e-12)


def test_the_stream_flag_keeps_the_description_valid():
    point, rig_name, fs, duration, safety = POINTS["motor-mfc1"]
    data = description.build(point, load_rig(rig_name).info, fs=fs, duration=duration, seed=0, rig_safety=safety)
    assert not description.decode(data).stream
    streamed = description.with_stream(data, True)
    assert description.decode(streamed).stream and description.with_stream(streamed, False) == data
