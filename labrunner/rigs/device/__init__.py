"""The loop on the device: run descriptions, the firmware's reference executor, sample blocks and
the host side of a device-loop run (docs/device-loop.md)."""
