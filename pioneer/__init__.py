"""P2OS for the Pioneer 2DX: packet codec, SIP decoding, host-side driver, robot-side emulator."""
