"""Benchmark of the piano's deploy tick (not a test): host compute per tick with its load compensation.

Usage::

    python bench/piano_tick.py [--policy checkpoints/lite_piano_arms.onnx] [--song ode_to_joy]
                               [--duration 20] [--repeats 2]

Runs ``bar-deploy --policy P --song S --duration D --target sim`` (the 3 s ramp, then the song) with the
piano's defaults (the hand-load tare and the load's inertia), with ``--load-inertia off`` and with
``--hand-load off``, each ``--repeats`` times, and prints each run's tick compute p50 / p99 / max and the
ONNX call's p50 / p99 from its ``run.json`` (``timing``: read state, observation, ONNX, the song source and
its key-pose reference, the load compensation, the command written; the sim target's physics is not in
it). The deploy tick's budget (1 ms p99) and the generated MLP's figure: docs/performance.md. The machine
may be shared: the load average is printed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

VARIANTS = (
    ("defaults (tare, inertia)", ()),
    ("--load-inertia off", ("--load-inertia", "off")),
    ("--hand-load off", ("--hand-load", "off")),
)
"""(label, extra ``bar-deploy`` flags) per timed configuration."""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default="checkpoints/lite_piano_arms.onnx", help="the piano policy file")
    p.add_argument("--song", default="ode_to_joy", help="the song played (a library name or a file)")
    p.add_argument("--duration", type=float, default=20.0, help="seconds per run, the ramp's 3 included")
    p.add_argument("--repeats", type=int, default=2, help="runs per configuration")
    args = p.parse_args()
    cpu = platform.processor() or platform.machine()
    print(f"piano deploy tick, {args.policy}, song {args.song}, {args.duration:g} s a run, {cpu}")
    print(f"  load average before {os.getloadavg()[0]:.2f}")
    for label, extra in VARIANTS:
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as log:
                cmd = ["bar-deploy", "--policy", args.policy, "--song", args.song]
                cmd += ["--duration", str(args.duration), "--target", "sim", "--log", log, *extra]
                done = subprocess.run(cmd, capture_output=True, text=True)
                if done.returncode != 0:
                    sys.exit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.strip()[-400:]}")
                (run,) = Path(log).glob("*/run.json")
                t = json.loads(run.read_text())["timing"]
            print(
                f"  {label:26s} {t['ticks']} ticks: compute p50 {t['compute_p50_ms']:.2f} ms, "
                f"p99 {t['compute_p99_ms']:.2f} ms, max {t['compute_max_ms']:.1f} ms; "
                f"ONNX p50 {t['infer_p50_ms']:.2f} ms, p99 {t['infer_p99_ms']:.2f} ms"
            )
    print(f"  load average after {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
