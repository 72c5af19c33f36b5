"""Serve a rig file's device (as JSON on argv[1]) from this process: the emulator in another
process than the host, as on a lab bench. A serial rig gets a new pty, whose name is printed;
``ready`` is printed when it serves; it stops when stdin closes. argv[2]: LinkFaults as JSON."""

from __future__ import annotations

import json
import sys

from labrunner.rigs.config import config_from_dict
from labrunner.rigs.transports.emulator import Emulator, device_link, pty_link, twin_for
from labrunner.rigs.transports.faults import LinkFaults


def main() -> None:
    config = config_from_dict(json.loads(sys.argv[1]))
    faults = LinkFaults(**json.loads(sys.argv[2])) if len(sys.argv) > 2 else None
    if config.kind == "serial":
        name, link = pty_link(config.parameters["node_id"])
        print(name, flush=True)
    else:
        link = device_link(config)
    emulator = Emulator(twin_for(config), link, paced=False, faults=faults).start()
    print("ready", flush=True)
    sys.stdin.read()
    emulator.stop()
    for exc in emulator.errors:
        print(f"emulator error: {exc!r}", file=sys.stderr)


if __name__ == "__main__":
    main()
