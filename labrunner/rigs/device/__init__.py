"""The loop on the device: run descriptions, the firmware's reference executor, sample blocks and
the host side of a device-loop run (docs/device-loop.md)."""

#: protocol faults the emulated device can be given (``labrunner emulate --fault-protocol``), for
#: ``labrunner conform``'s own tests: it runs a description whose CRC-32 fails, or of another
#: version; it goes on after the host's SAFE/STOP; it has no host-silence watchdog
PROTOCOL_FAULTS = ("no-crc-check", "any-version", "ignore-stop", "no-watchdog")
