"""The done-criterion of docs/control-laws.md: a device whose law is written from the documents
alone — labrunner/rigs/device/doclaw.py in the emulator's place of the reference executor — passes
``labrunner conform``'s vectors, across the link, for every rig kind; with one constant of its
law wrong it fails them."""

from __future__ import annotations

import threading

import pytest

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.device import blocks, conform, description, doclaw, executor
from labrunner.rigs.device.description import DescriptionError
from labrunner.rigs.transports.emulator import Emulator, device_link, twin_for
from tests.test_deviceloop_link import rig_file


def _document_device(emulator: Emulator, law=doclaw.run):
    """Replace the emulated device's executor by the document's law (sensor-table runs only)."""
    info = emulator.rig.info

    def execute(data: bytes, hook, on_accept, tick) -> executor.DeviceRun:
        d = description.decode(data)
        if d.kind not in description.DEVICE_KINDS:
            raise DescriptionError(f"controller kind {d.kind!r} is not in this firmware")
        if (d.n_inputs, d.n_outputs) != (len(info.inputs), len(info.outputs)) or d.sensor_table is None:
            raise DescriptionError("this document-built device runs sensor-table descriptions of its own channels")
        on_accept(d)
        done: dict = {}
        worker = threading.Thread(
            target=lambda: done.update(out=law(d, [s.name for s in info.inputs], [s.name for s in info.outputs]))
        )
        worker.start()
        while worker.is_alive():  # a firmware reports PROGRESS while it runs (the host gives up after 1 s of silence)
            worker.join(0.05)
            tick(0)
        rows, v = done["out"]
        n = len(rows)
        verdict = blocks.Verdict(
            v["status"], n, n, 0, v.get("monitor", ""), v.get("time", float("nan")), v.get("value", float("nan")),
            v.get("threshold", float("nan")), device_us=blocks.tick_us(n, d.fs),
        )  # fmt: skip
        return executor.DeviceRun(rows.astype("float32"), verdict, {})

    emulator.device_loop.session.execute = execute  # what the bulk session calls with a complete description


@pytest.mark.slow
@pytest.mark.parametrize("name, medium", [("motor-mfc1", "canfd"), ("valve-mfc1", "canfd"), ("plate-mfc", "canfd")])
def test_a_device_built_from_the_documents_passes_conform(name, medium):
    config = config_from_dict(rig_file(name, medium))
    emulator = Emulator(twin_for(config), device_link(config), paced=False)
    _document_device(emulator)
    emulator.start()
    try:
        checks = conform.conform(config, protocol=False)
    finally:
        emulator.stop()
    assert all(c.passed for c in checks), [c for c in checks if not c.passed]
    assert len(checks) == 1 + len(conform.cases_for(config.info.kind))


@pytest.mark.slow
def test_the_same_device_with_its_gain_off_by_one_percent_fails():
    config = config_from_dict(rig_file("motor-mfc1", "canfd"))
    emulator = Emulator(twin_for(config), device_link(config), paced=False)

    def off(d, inputs, outputs):
        if "gamma" in d.law:
            d.law["gamma"] = d.law["gamma"] * 1.01
        return doclaw.run(d, inputs, outputs)

    _document_device(emulator, off)
    emulator.start()
    try:
        checks = conform.conform(config, ["mfc1-motor-velocity", "open-loop-motor-sine"], protocol=False)
    finally:
        emulator.stop()
    assert [c.passed for c in checks] == [True, False, True]
    assert "law diverged@tick" in checks[1].detail
