"""One control tick over the emulated CAN buses: host time, and the rate the wire could sustain.

    python bench/can_tick.py [--ticks 2000] [--mode realtime|lockstep|both]

A tick = ``RobstrideGroup.exchange_mit``: 7 MIT frames out and 7 type-2 replies in on each of the two
buses (14 + 14), with every motor's CAN watchdog armed (0.2 s) as activation arms it, through python-can
``virtual`` buses to the in-process emulator (its threads answer; in realtime mode a third thread steps
MuJoCo at 500 Hz; in lockstep mode every tick also runs 20 ms of physics before the replies, so that number
includes 10 physics steps).

The wire limit is computed from the tick's actual frames: each extended 8-byte frame is laid out bit by
bit (SOF, 29-bit id with SRR/IDE, RTR, r1, r0, DLC, data, CRC-15), stuffed (a complement bit after 5
equal bits, SOF..CRC), plus 13 unstuffed bits (CRC delimiter, ACK slot + delimiter, EOF 7, IFS 3).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import can
import numpy as np

from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride.emulator import RobstrideEmulator
from bar_policy.robstride.group import RobstrideGroup
from bar_policy.robstride.watchdog import arm_can_timeout

BITRATE = 1_000_000


def crc15(bits: list[int]) -> list[int]:
    """CAN CRC-15 (polynomial 0x4599) of a bit sequence, as 15 bits MSB first."""
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return [(crc >> (14 - i)) & 1 for i in range(15)]


def frame_bits(arbitration_id: int, data: bytes) -> int:
    """Bits on the wire of one extended data frame, with its actual bit stuffing and 3 bits of IFS."""

    def bits(value: int, n: int) -> list[int]:
        return [(value >> (n - 1 - i)) & 1 for i in range(n)]

    # SOF, base id, SRR, IDE, extended id, RTR, r1, r0
    body = [0, *bits(arbitration_id >> 18, 11), 1, 1, *bits(arbitration_id & 0x3FFFF, 18), 0, 0, 0]
    body += bits(len(data), 4) + [b for byte in data for b in bits(byte, 8)]
    body += crc15(body)
    stuffed, run, last = 0, 0, None
    for b in body:
        run = run + 1 if b == last else 1
        last = b
        if run == 5:
            stuffed += 1
            last, run = 1 - b, 1  # the stuff bit starts a new run
    return len(body) + stuffed + 13


def bench(mode: str, ticks: int) -> dict[str, float]:
    robot = load_robot("arms")
    k = f"bench-{mode}-{time.monotonic_ns()}"
    channels = {"can0": f"{k}-can0", "can1": f"{k}-can1"}
    emu = RobstrideEmulator(robot, channels, mode=mode).start()
    buses = {i: can.Bus(interface="virtual", channel=c) for i, c in channels.items()}
    group = RobstrideGroup.from_robot(robot, buses, reply_timeout=0.05)
    try:
        for bus in group.buses:  # as activation does: the emulator then checks every motor's watchdog
            arm_can_timeout(bus)
        group.enable()
        cmd = MitCommand.position(robot.pose("arms_hanging"), robot.kp, robot.kd)
        for _ in range(50):  # warm up
            group.exchange_mit(cmd)
        host = np.empty(ticks)
        cpu = np.empty(ticks)
        p0 = time.process_time()
        for i in range(ticks):
            c0, t0 = time.thread_time(), time.perf_counter()
            group.exchange_mit(cmd)
            host[i] = time.perf_counter() - t0
            cpu[i] = time.thread_time() - c0
        proc = (time.process_time() - p0) / ticks
        # wire time of one tick on can0 from the frames actually exchanged: one more tick, recorded by a
        # listener node (attached only now, so its copies do not slow the timed ticks)
        listener = can.Bus(interface="virtual", channel=channels["can0"])
        group.exchange_mit(cmd)
        time.sleep(0.01)
        frames = list(iter(lambda: listener.recv(timeout=0), None))
        listener.shutdown()
        wire_bits = sum(frame_bits(m.arbitration_id, bytes(m.data)) for m in frames)
        group.stop()
    finally:
        group.shutdown()
        emu.close()
    return {
        "p50_ms": float(np.percentile(host, 50) * 1e3),
        "p99_ms": float(np.percentile(host, 99) * 1e3),
        "max_ms": float(host.max() * 1e3),
        "mean_ms": float(host.mean() * 1e3),
        "cpu_p50_ms": float(np.percentile(cpu, 50) * 1e3),
        "cpu_p99_ms": float(np.percentile(cpu, 99) * 1e3),
        "proc_ms": proc * 1e3,
        "wire_bits": wire_bits,
        "n_frames": len(frames),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ticks", type=int, default=2000)
    p.add_argument("--mode", choices=("realtime", "lockstep", "both"), default="both")
    args = p.parse_args()
    modes = ("realtime", "lockstep") if args.mode == "both" else (args.mode,)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(
        f"python {sys.version.split()[0]}, python-can {can.__version__}, {args.ticks} ticks per mode, "
        f"{os.cpu_count()} CPUs, load average {load:.2f}"
    )
    print("host time per tick (14 MIT frames out, 14 replies in, two virtual buses + emulator threads):")
    wire = None
    for mode in modes:
        r = bench(mode, args.ticks)
        wire = r
        print(
            f"  {mode:<9} wall p50 {r['p50_ms']:.3f} ms  p99 {r['p99_ms']:.3f} ms  "
            f"mean {r['mean_ms']:.3f} ms  max {r['max_ms']:.3f} ms | driver-thread CPU "
            f"p50 {r['cpu_p50_ms']:.3f} ms  p99 {r['cpu_p99_ms']:.3f} ms | process CPU (driver + "
            f"emulator threads) {r['proc_ms']:.3f} ms/tick"
        )
    assert wire is not None
    bits = wire["wire_bits"]
    print("wire limit at 1 Mbit/s per bus (7 motors, 7 commands + 7 replies per tick, buses in parallel):")
    for name, b in (
        ("nominal 131-bit frames", 14 * 131),
        ("worst-case 160-bit frames", 14 * 160),
        (f"this tick's frames, stuffed ({wire['n_frames']} frames)", bits),
    ):
        t = b / BITRATE
        print(f"  {name:<42} {b:5d} bits = {t * 1e3:.3f} ms -> {1 / t:6.0f} Hz (70% load: {0.7 / t:4.0f} Hz)")
    lo = frame_bits(0x01000000 | 0x555500 | 0x0B, bytes([0x55] * 8))
    hi = frame_bits(0x00000000, bytes(8))
    print(f"  frame-length check: alternating bits {lo} bits (131 + CRC stuffing), all-zero frame {hi} bits")
    return 0


if __name__ == "__main__":
    sys.exit(main())
