"""Serve the C device core on a CAN bus: ``liblabdevice_can.so`` (``make -C firmware host``)
loaded with ctypes, its frames carried by python-can on the bus a can rig file names (e.g.
``interface = "udp_multicast"``). The core decides everything CAN: identifiers, which frames are
its node's (its own echoes on a multicast bus are dropped there), CAN FD padding.

    python firmware/port/can/can_bridge.py LIB RIG.toml [--plant] [--fault-law KEY=FACTOR]

prints ``serving`` once the bus is open, then runs until interrupted.
"""

from __future__ import annotations

import argparse
import ctypes
import signal
import threading

import can

from labrunner.rigs.config import load_rig_config
from labrunner.rigs.transports.emulator import device_link

KINDS = {"dcmotor": 1, "valve": 2, "plate": 3}
RECV = ctypes.CFUNCTYPE(
    ctypes.c_int,
    ctypes.POINTER(ctypes.c_uint32),
    ctypes.POINTER(ctypes.c_int),
    ctypes.POINTER(ctypes.c_uint8),
    ctypes.POINTER(ctypes.c_uint8),
)
SEND = ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.POINTER(ctypes.c_uint8), ctypes.c_uint8, ctypes.c_int)


def serve(lib_path: str, rig: str, plant: bool, fault: tuple[str, float], stop: threading.Event) -> None:
    """Run the device until ``stop`` is set (prints ``serving`` once ready)."""
    config = load_rig_config(rig)
    bus: can.BusABC = device_link(config).bus
    p = config.parameters

    def recv(id_, extended, data, length) -> int:
        msg = bus.recv(0.0)
        if msg is None or msg.is_error_frame or msg.is_remote_frame:
            return 0
        id_[0], extended[0], length[0] = msg.arbitration_id, int(msg.is_extended_id), min(len(msg.data), 64)
        ctypes.memmove(data, bytes(msg.data[:64]), length[0])
        return 1

    def send(id_, data, length, fd) -> None:
        payload = ctypes.string_at(data, length)
        bus.send(
            can.Message(arbitration_id=id_, data=payload, is_extended_id=False, is_fd=bool(fd), bitrate_switch=bool(fd))
        )

    lib = ctypes.CDLL(lib_path)
    callbacks = (RECV(recv), SEND(send))  # kept referenced while the device runs
    lib.lab_can_open.argtypes = [ctypes.c_int] * 4 + [ctypes.c_char_p, ctypes.c_double, RECV, SEND]
    kind = KINDS[p["device"]]
    if lib.lab_can_open(kind, p["node_id"], int(p["fd"]), int(plant), fault[0].encode(), fault[1], *callbacks) != 0:
        raise SystemExit(f"can_bridge: the core refused kind {p['device']}, node {p['node_id']} (plant {plant})")
    print("serving", flush=True)
    try:
        while not stop.is_set():
            lib.lab_can_poll()
    finally:
        bus.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("lib")
    parser.add_argument("rig")
    parser.add_argument("--plant", action="store_true")
    parser.add_argument("--fault-law", default="=1")
    args = parser.parse_args()
    key, _, factor = args.fault_law.partition("=")
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    serve(args.lib, args.rig, args.plant, (key, float(factor)), stop)


if __name__ == "__main__":
    main()
