"""Benchmark of the load-inertia feed-forward (not a test): host compute per tick of its reference arm.

Usage::

    python bench/load_inertia_tick.py [--ticks 2000] [--scene piano|none]

``deploy.load_inertia.LoadInertia.step`` each tick advances the nominal robot one control period (10 physics
steps of 2 ms) in the task's scene and computes the feed-forward at the measured pose; this times it on a
command that sweeps the arms through a piano-like motion (a 1.5 Hz sine of 0.05 rad on every joint around
piano_ready), in the keyboard's scene (``piano``) or the robot alone (``none``). It prints p50, p99 and the
largest per-tick time in ms, and the load average (the machine may be shared). The deploy tick's own
budget and figure: docs/performance.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from bar_policy.deploy.load_inertia import LoadInertia
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mit import MitCommand

DT = 0.02
"""The piano policy's control period, s."""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ticks", type=int, default=2000, help="ticks timed (after 50 of warm-up)")
    p.add_argument("--scene", choices=("piano", "none"), default="piano", help="the reference's scene")
    args = p.parse_args()
    scene = None
    if args.scene == "piano":
        from bar_policy.tasks.piano.keyboard import compact_config
        from bar_policy.tasks.piano.scene import keyboard_scene

        scene = keyboard_scene(compact_config())
    robot = load_robot("arms")
    q0 = np.asarray(robot.pose("piano_ready"))
    ff = LoadInertia("arms", DT, scene)
    ff.start(q0, np.zeros(q0.size))
    masses = np.array([0.5, 0.5])
    times = []
    for k in range(args.ticks + 50):
        q_cmd = q0 + 0.05 * np.sin(2 * np.pi * 1.5 * k * DT)
        cmd = MitCommand.position(q_cmd, robot.kp, robot.kd)
        t0 = time.perf_counter()
        ff.step(cmd, q_cmd, masses)
        if k >= 50:
            times.append(time.perf_counter() - t0)
    ms = 1e3 * np.array(times)
    cpu = platform.processor() or platform.machine()
    print(f"load inertia step, scene {args.scene}, {args.ticks} ticks, {cpu}")
    print(f"  p50 {np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, max {ms.max():.3f} ms")
    print(f"  load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
