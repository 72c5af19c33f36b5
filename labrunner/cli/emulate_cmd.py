"""``labrunner emulate RIG.toml``: serve a rig file's device as its simulated twin (the firmware's reference).

A ``can`` rig file: the emulator joins the rig's bus as the device (e.g. ``udp_multicast`` on
loopback). A ``serial`` rig file: it creates a pty pair and prints ``port /dev/pts/N`` on the
first line; run the host against that port. The device is paced in real time unless
``--free-run``; the fault options inject link faults into what it sends (tests, rehearsals).
"""

from __future__ import annotations

import argparse
import math

from labrunner.cli.argtypes import numeric, positive_int

_probability = numeric(float, "in [0, 1]")
_non_negative = numeric(float, ">= 0")
#: device-loop protocol faults (labrunner.rigs.device.emulated.DeviceLoop.protocol_faults), for
#: ``labrunner conform``'s own tests: it runs a description whose CRC-32 fails, or of another
#: version; it goes on after the host's SAFE/STOP; it has no host-silence watchdog
PROTOCOL_FAULTS = ("no-crc-check", "any-version", "ignore-stop", "no-watchdog")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "emulate",
        help="serve a can/serial rig file's device as its twin (paced; fault injection)",
        description="Serve the device of a can or serial rig file as its simulated twin, speaking protocol v1 "
        "(docs/protocol.md): on the rig's CAN bus, or on a new pty whose name it prints. Ctrl-C stops.",
    )
    p.add_argument("rig", metavar="RIG.toml", help="a can or serial rig file")
    p.add_argument("--interface", metavar="NAME", help="a CAN rig's python-can interface instead of the file's")
    p.add_argument("--channel", metavar="NAME", help="a CAN rig's channel instead of the file's")
    p.add_argument(
        "--free-run", action="store_true", help="tick as soon as the host commits an input (no real-time pacing)"
    )
    p.add_argument(
        "--drop", type=_probability, default=0.0, metavar="P", help="drop each sent frame with probability P"
    )
    p.add_argument("--delay", type=_non_negative, default=0.0, metavar="MS", help="send every frame MS ms late")
    p.add_argument(
        "--garbage", type=_probability, default=0.0, metavar="P", help="garbage after a frame with probability P"
    )
    p.add_argument(
        "--duplicate", type=_probability, default=0.0, metavar="P", help="send a frame twice with probability P"
    )
    p.add_argument(
        "--stale", type=_probability, default=0.0, metavar="P", help="repeat an old frame with probability P"
    )
    p.add_argument(
        "--spoof", type=_probability, default=0.0, metavar="P", help="a frame with the host's id with probability P"
    )
    p.add_argument(
        "--error-frames", type=_probability, default=0.0, metavar="P", help="a CAN error frame with probability P"
    )
    p.add_argument(
        "--replay",
        action="store_true",
        help="host loop: before each measurement, replay the previous run's frame of that tick and channel",
    )
    p.add_argument(
        "--clock-reset-tick",
        type=positive_int,
        default=0,
        metavar="K",
        help="host loop: restart the device's clock at 0 from tick K of each run (a device reset)",
    )
    p.add_argument(
        "--die-after",
        type=_non_negative,
        default=math.inf,
        metavar="S",
        help="fall silent for good S seconds after the first run began (host loop: SETUP; device loop: ACCEPT)",
    )
    p.add_argument(
        "--fault-law",
        type=_law_fault,
        action="append",
        default=[],
        metavar="KEY=FACTOR",
        help="run a deliberately wrong law in the device loop: multiply controller.KEY by FACTOR where a point "
        "sets it (e.g. gamma=1.02); the host's law check must catch it",
    )
    p.add_argument(
        "--fault-protocol",
        choices=PROTOCOL_FAULTS,
        action="append",
        default=[],
        help="a device-loop protocol fault (for testing `labrunner conform`): run descriptions with a bad CRC-32 "
        "or another version, go on after SAFE/STOP, or have no host-silence watchdog",
    )
    p.add_argument(
        "--float32",
        action="store_true",
        help="compute the device loop's laws in IEEE single precision (as a Cortex-M4F firmware would) and "
        "announce FLOAT32 in IDENTITY: the host checks the runs with the float32 tolerance",
    )
    p.add_argument(
        "--input-delay",
        type=numeric(int, ">= 0"),
        default=0,
        metavar="N",
        help="apply each input N ticks late (both loops; the law's u is still what is logged): a fault the law "
        "check and conform cannot see, which check-rig's dead-time test catches",
    )
    p.add_argument("--seed", type=numeric(int, ">= 0"), default=0, help="seed of the fault injection")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="run the device's loop at SCHED_FIFO priority (root or CAP_SYS_NICE), like firmware on a timer",
    )
    p.set_defaults(func=main)


def _law_fault(text: str) -> tuple[str, float]:
    """``KEY=FACTOR`` of ``--fault-law``: a controller key and a finite factor."""
    key, eq, value = text.partition("=")
    try:
        factor = float(value)
    except ValueError:
        factor = math.nan
    if not (eq and key.isidentifier() and math.isfinite(factor)):
        raise argparse.ArgumentTypeError(f"needs KEY=FACTOR with a controller key and a finite number, got {text!r}")
    return key, factor


def main(args: argparse.Namespace) -> int:
    import signal
    import sys
    import threading

    from labrunner.errors import InvalidParameter
    from labrunner.rigs.config import load_rig_config
    from labrunner.rigs.device.emulated import use_float32
    from labrunner.rigs.transports.emulator import Emulator, device_link, pty_link, twin_for
    from labrunner.rigs.transports.faults import LateInputRig, LinkFaults

    for name in ("drop", "garbage", "duplicate", "stale", "spoof", "error_frames"):
        if not 0.0 <= getattr(args, name) <= 1.0:
            raise InvalidParameter(f"--{name.replace('_', '-')}", f"must be in [0, 1], got {getattr(args, name)!r}")
    for name in ("delay", "die_after"):
        if getattr(args, name) < 0:
            raise InvalidParameter(f"--{name.replace('_', '-')}", f"must be >= 0, got {getattr(args, name)!r}")
    if args.realtime and args.free_run:
        raise InvalidParameter("--realtime", "paces the device's clock; it cannot be used with --free-run")
    config = load_rig_config(args.rig, link={"interface": args.interface, "channel": args.channel})
    if config.kind not in ("can", "serial"):
        raise InvalidParameter("rig.kind", f"emulate serves can or serial rig files, got {config.kind!r}")
    faults = LinkFaults(
        drop=args.drop,
        delay_ms=args.delay,
        garbage=args.garbage,
        duplicate=args.duplicate,
        stale=args.stale,
        spoof=args.spoof,
        error_frame=args.error_frames,
        die_after_s=args.die_after,
        replay=args.replay,
        clock_reset_tick=args.clock_reset_tick,
        seed=args.seed,
    )
    if config.kind == "serial":
        port, link = pty_link(config.parameters["node_id"])
        print(f"port {port}", flush=True)
    else:
        link = device_link(config)
    twin = twin_for(config)
    if args.input_delay:
        twin = LateInputRig(twin, args.input_delay)
    emulator = Emulator(twin, link, paced=not args.free_run, faults=faults, realtime=args.realtime)
    if args.float32:
        use_float32(emulator)
    emulator.device_loop.law_fault = dict(args.fault_law)
    emulator.device_loop.protocol_faults = set(args.fault_protocol)
    emulator.start()
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    pacing = ("free-running" if args.free_run else "paced") + (", real-time" if emulator.realtime else "")
    print(f"serving the {config.parameters['device']} twin of {config.source} ({pacing}); Ctrl-C stops", flush=True)
    try:
        while not done.wait(0.2) and emulator.is_alive():
            pass
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    for exc in emulator.errors:
        print(f"labrunner emulate: {type(exc).__name__}: {exc}", file=sys.stderr)
    return 0
