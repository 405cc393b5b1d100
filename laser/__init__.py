"""SICK LMS2xx: telegram codec and CRC, host-side reader, device-side emulator."""
