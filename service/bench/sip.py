"""P2OS SIPs: decoding throughput of the incremental reader, and command-to-SIP latency over a pty.

Throughput: a realistic stream (a robot driving curves, 4 sonar readings per SIP, as the emulator
produces them) is encoded once, concatenated and fed to :class:`pioneer.packet.PacketReader` in
4 KiB chunks (as a serial port delivers them); each packet is decoded with
:func:`pioneer.sip.decode_sip` and integrated into odometry, on one core.

Latency: the driver and the emulator talk over a real pty; each VEL command (sent at a random
phase of the SIP cycle) until the driver has the first SIP reporting the new wheel speed. P2OS
answers once per SIP cycle, so the median is about half a cycle (50 ms at the 100 ms cycle); at
9600 baud a 42-byte SIP alone takes 44 ms on a real line, which a pty does not reproduce.

Timings are the best of several runs: other processes on the machine only ever add time.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import replace

import numpy as np

from pioneer.emulator import PioneerEmulator
from pioneer.odometry import OdometryIntegrator
from pioneer.packet import PacketReader, frame
from pioneer.params import P2DX
from pioneer.physics import DiffDrive
from pioneer.sip import decode_sip, encode_sip
from serialport.ptys import open_pty

NAME = "sip"
HELP = "P2OS SIPs decoded per second by the reader (goal >= 100,000/s); VEL-to-SIP latency over a pty"
CHUNK = 4096


def _stream(n: int) -> list[bytes]:
    """``n`` framed SIPs of a robot driving curves at 0.1 s steps, as the emulator encodes them."""
    body = DiffDrive(replace(P2DX, trans_accel=1000, rot_accel=200))
    body.motors_enabled = True
    emu = PioneerEmulator(-1, body=body)  # never started: only its SIP builder is used
    out = []
    for i in range(n):
        if i % 50 == 0:
            body.set_velocity(0.8 * math.sin(i / 200.0) + 0.2)
            body.set_rotation(0.6 * math.cos(i / 130.0))
        body.step(0.1)
        out.append(frame(encode_sip(emu.sip())))
    return out


def _throughput(frames: list[bytes], repeats: int, odometry: bool) -> tuple[float, float]:
    """SIPs per second through the reader and decode_sip (and the odometry integrator), by the wall
    clock and by this process's CPU time (which other processes on the machine do not inflate)."""
    stream = b"".join(frames)
    best = cpu = math.inf
    for _ in range(repeats):
        reader, odo = PacketReader(), OdometryIntegrator(P2DX)
        t0, c0 = time.perf_counter(), time.process_time()
        if odometry:
            for i in range(0, len(stream), CHUNK):
                for pkt in reader.feed(stream[i : i + CHUNK]):
                    odo.update(decode_sip(pkt.data), 0.0)
        else:
            for i in range(0, len(stream), CHUNK):
                for pkt in reader.feed(stream[i : i + CHUNK]):
                    decode_sip(pkt.data)
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
        assert reader.packets_ok == len(frames)
    return len(frames) / best, len(frames) / cpu


def _per_sip(frames: list[bytes]) -> np.ndarray:
    """Microseconds per SIP fed one at a time (frame, decode, odometry), as the driver sees them."""
    reader, odo = PacketReader(), OdometryIntegrator(P2DX)
    per = np.empty(len(frames))
    for i, f in enumerate(frames):
        t0 = time.perf_counter_ns()
        for pkt in reader.feed(f):
            odo.update(decode_sip(pkt.data), 0.0)
        per[i] = (time.perf_counter_ns() - t0) / 1000.0
    return per


def _latency(commands: int) -> np.ndarray:
    from pioneer.driver import Pioneer

    quick = replace(P2DX, trans_accel=100_000, trans_decel=100_000)  # the new speed within one step
    out = []
    rng = random.Random(1)
    with open_pty() as pair, PioneerEmulator(pair.master, quick), Pioneer(pair.path, params=quick) as robot:
        for i in range(commands):
            v = 0.1 + 0.01 * (i % 20)
            robot.wait_odometry(1.0)
            time.sleep(rng.uniform(0.0, P2DX.sip_cycle))  # commands come at any phase of the cycle
            t0 = time.monotonic()
            robot.set_velocity(v if i % 2 else -v, 0.0)
            target = round((v if i % 2 else -v) * 1000)
            while True:
                odo = robot.wait_odometry(1.0)
                if odo is None:
                    raise TimeoutError("no SIP within 1 s during the latency benchmark")
                if odo.sip.left_vel == target:
                    out.append(odo.t - t0)
                    break
        robot.stop()
    return np.array(out) * 1000.0


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    frames = _stream(20_000 if quick else 200_000)
    repeats = 2 if quick else 5
    rate, rate_cpu = _throughput(frames, repeats, odometry=False)
    rate_odo, rate_odo_cpu = _throughput(frames, repeats, odometry=True)
    med, p99 = np.percentile(_per_sip(frames), [50, 99])
    nbytes = sum(map(len, frames)) / len(frames)
    print(f"  {len(frames):,} SIPs of {nbytes:.0f} bytes on average (4 sonar readings each), 4 KiB chunks")
    print(f"  reader: {rate:,.0f} SIPs/s wall, {rate_cpu:,.0f} SIPs/s CPU "
          "(frame + checksum + decode_sip; goal >= 100,000/s)")
    print(f"  reader + odometry: {rate_odo:,.0f} SIPs/s wall, {rate_odo_cpu:,.0f} SIPs/s CPU")
    print(f"  per SIP fed alone (frame + decode + odometry): median {med:.1f} us, p99 {p99:.1f} us")
    lat = _latency(10 if quick else 50)
    lmed, lp99 = np.percentile(lat, [50, 99])
    print(f"  VEL -> first SIP reporting it, over a pty, {len(lat)} commands: median {lmed:.1f} ms, "
          f"p99 {lp99:.1f} ms (bounded by the 100 ms SIP cycle)")
    return {"sips_per_s": rate, "sips_per_s_cpu": rate_cpu, "sips_per_s_with_odometry": rate_odo,
            "sips_per_s_with_odometry_cpu": rate_odo_cpu, "median_us": float(med),
            "p99_us": float(p99), "latency_median_ms": float(lmed), "latency_p99_ms": float(lp99)}
