"""Real-rig transports, protocol v1 (docs/protocol.md).

- :mod:`.protocol` (kinds, CAN id plan, frames), :mod:`.messages` (the 8-byte messages),
  :mod:`.framing` (serial COBS + CRC-16), :mod:`.link` (the Link v1 API and its counters);
- :mod:`.can`, :mod:`.serial`: the links and the host's rigs; :mod:`.remote`: the host loop;
  :mod:`.diagnostics`: the per-run record; :mod:`.checkrig`: ``labrunner check-rig``;
- :mod:`.emulator`, :mod:`.hostloop_device`, :mod:`.faults`, :mod:`.realtime`: the emulated device;
- :mod:`.bulk`, :mod:`.linkload`: the device loop's transfers and the link-load model (docs/device-loop.md).
"""
