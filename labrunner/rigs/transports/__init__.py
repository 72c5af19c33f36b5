"""Real-rig transports: the frame protocol, CAN (python-can) and serial (pyserial) rigs, a firmware emulator."""
