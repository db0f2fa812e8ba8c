"""Benchmark of the deploy runtime (not a test): host compute per tick, 500 Hz mock loop jitter, sim speed.

Usage::

    python bench/deploy_tick.py [--policy x.onnx] [--hidden 256] [--ticks 5000] [--loop-s 5]
                                [--sim-s 20] [--rt-priority 50]

Without ``--policy`` it builds a 2-hidden-layer tanh MLP (``--hidden`` wide) with the test policy factory
(needs ``onnx``, which is fine here: this is not deploy code).

Targets (2-core CPU): compute p99 <= 1 ms; 500 Hz on the mock with p99 jitter <= 0.5 ms; the sim
target headless at >= 20x real time. The machine may be shared: the load average is printed with the numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "deploy"))

from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.targets.mock import MockTarget
from bar_policy.deploy.targets.sim import SimTarget
from bar_policy.tasks.reach.commands import SampledCommands


def _policy_files(args: argparse.Namespace, tmp: Path) -> tuple[Path, Path]:
    """(50 Hz policy, the same network declared at 500 Hz for the loop test)."""
    from policy_factory import default_metadata, make_policy_file

    if args.policy:
        meta = load_policy(args.policy).metadata
        p500 = make_policy_file(
            tmp / "p500.onnx", metadata=dataclasses.replace(meta, policy_dt=0.002), hidden=args.hidden
        )
        return Path(args.policy), p500
    p50 = make_policy_file(tmp / "p50.onnx", hidden=args.hidden)
    p500 = make_policy_file(tmp / "p500.onnx", metadata=default_metadata(policy_dt=0.002), hidden=args.hidden)
    return p50, p500


class _Fifo:
    """SCHED_FIFO for this thread inside the block (if permitted)."""

    def __init__(self, priority: int | None) -> None:
        self.priority = priority
        self.active = False

    def __enter__(self) -> _Fifo:
        if self.priority is not None:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
                self.active = True
            except (AttributeError, OSError) as e:
                print(f"(SCHED_FIFO not permitted: {e})")
        return self

    def __exit__(self, *exc: object) -> None:
        if self.active:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def bench_compute(path: Path, ticks: int) -> dict[str, float]:
    """Host compute per tick (state -> obs -> ONNX -> command written) on the mock, no pacing."""
    pol = load_policy(path)
    target = MockTarget(pol.robot.mode)
    cfg = RuntimeConfig(duration=1.0, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    rt = Runtime(pol, target, SampledCommands(pol.obs_manager.command_names, seed=0), cfg)
    for k in range(200):  # warm-up
        rt._tick(k, k * 0.02, False)
    compute = np.empty(ticks)
    for k in range(ticks):
        compute[k] = rt._tick(200 + k, (200 + k) * 0.02, False)["compute"]
    return {
        "p50_ms": float(np.percentile(compute, 50) * 1e3),
        "p99_ms": float(np.percentile(compute, 99) * 1e3),
        "max_ms": float(compute.max() * 1e3),
    }


def bench_loop(path: Path, seconds: float, rt_priority: int | None) -> dict[str, float]:
    """The paced loop at 500 Hz on the mock target."""
    pol = load_policy(path, control_dt=0.002)
    cfg = RuntimeConfig(
        control_dt=0.002,
        duration=seconds,
        start_mode="policy",
        rt_priority=rt_priority,
        safety=SafetyConfig(ramp_time=0.0, max_overruns=0),
    )
    rt = Runtime(pol, MockTarget(pol.robot.mode), SampledCommands(pol.obs_manager.command_names), cfg)
    return rt.run().timing.summary()


def bench_sim(path: Path, seconds: float) -> dict[str, float]:
    """Real-time factor of the sim target: whole runtime (policy 50 Hz, physics 500 Hz), headless."""
    pol = load_policy(path)
    sim = SimTarget(pol.robot.mode)
    cfg = RuntimeConfig(duration=seconds, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    rt = Runtime(pol, sim, SampledCommands(pol.obs_manager.command_names, seed=0), cfg)
    s = rt.run().timing.summary()
    # Physics alone (target advance with a fixed command), for reference.
    sim.reset()
    t0 = time.perf_counter()
    for _ in range(round(seconds / 0.02)):
        sim.advance(0.02)
    physics_rtf = seconds / (time.perf_counter() - t0)
    return {"runtime_rtf": s["realtime_factor"], "physics_only_rtf": physics_rtf}


def main() -> None:
    """Run the three benchmarks and print the numbers."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", help="ONNX policy (default: a generated MLP)")
    ap.add_argument("--hidden", type=int, default=256, help="hidden width of the generated MLP")
    ap.add_argument("--ticks", type=int, default=5000, help="ticks for the compute benchmark")
    ap.add_argument("--loop-s", type=float, default=5.0, help="seconds of the 500 Hz loop")
    ap.add_argument("--sim-s", type=float, default=20.0, help="simulated seconds for the sim benchmark")
    ap.add_argument("--rt-priority", type=int, default=50, help="SCHED_FIFO priority for the second loop run")
    args = ap.parse_args()
    print(
        f"host: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"python {platform.python_version()}"
    )
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        p50, p500 = _policy_files(args, Path(tmp))
        desc = args.policy or f"generated MLP 54-{args.hidden}-{args.hidden}-14 (tanh)"
        print(f"policy: {desc}")
        for prio in (None, args.rt_priority):
            label = "normal scheduler" if prio is None else f"SCHED_FIFO {prio}"
            with _Fifo(prio):
                c = bench_compute(p50, args.ticks)
            print(
                f"[compute, {label}] state->obs->ONNX->command per tick over {args.ticks} ticks: "
                f"p50 {c['p50_ms']:.3f} ms  p99 {c['p99_ms']:.3f} ms  max {c['max_ms']:.3f} ms"
                "  (target p99 <= 1 ms)"
            )
        for prio in (None, args.rt_priority):
            s = bench_loop(p500, args.loop_s, prio)
            label = "normal scheduler" if prio is None else f"SCHED_FIFO {prio}"
            print(
                f"[loop 500 Hz mock, {label}] {s['ticks']} ticks in {s['wall_s']:.3f} s "
                f"({s['rate_hz']:.1f} Hz): "
                f"jitter p50 {s['jitter_p50_ms']:.3f} ms  p99 {s['jitter_p99_ms']:.3f} ms  "
                f"max {s['jitter_max_ms']:.3f} ms  overruns {s['overruns']}  "
                f"compute p99 {s['compute_p99_ms']:.3f} ms"
                "  (target p99 jitter <= 0.5 ms)"
            )
        for prio in (None, args.rt_priority):
            label = "normal scheduler" if prio is None else f"SCHED_FIFO {prio}"
            with _Fifo(prio):
                r = bench_sim(p50, args.sim_s)
            print(
                f"[sim, {label}] headless real-time factor over {args.sim_s:g} s: "
                f"runtime {r['runtime_rtf']:.1f}x "
                f"(physics alone {r['physics_only_rtf']:.1f}x)  (target >= 20x)"
            )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
