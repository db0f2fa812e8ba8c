"""Benchmark of the run log (not a test): writer CPU and bytes per tick, loop jitter with and without it.

Usage::

    python bench/deploy_log.py [--ticks 2000] [--loop-s 10] [--rounds 2]

1. The writer thread's work per tick (``McapRunWriter.write_tick``: JSON encoding, MCAP records, a zstd
   chunk every 25 ticks), as thread CPU time, on a 14-joint reach row; the MCAP and NPZ bytes per tick.
2. The paced 50 Hz loop on the mock target with the zero-size (linear) test policy, alternating runs with
   ``log_dir`` and without, so a shared machine's load affects both alike: jitter p50 / p99 / max, compute
   p99, overruns.

The machine may be shared: the load average is printed with the numbers.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "deploy"))

from bar_policy.deploy.log.files import log_fields
from bar_policy.deploy.log.mcap_write import McapRunWriter
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.deploy.targets.mock import MockTarget
from bar_policy.tasks.reach.commands import SampledCommands


def bench_writer(ticks: int) -> dict[str, float]:
    """Thread CPU per tick of the MCAP encoding, and the sizes per tick."""
    fields = log_fields(14, 14, 54, ("target_pos_left", "target_pos_right"))
    rng = np.random.default_rng(0)
    rows = {k: rng.standard_normal((ticks, *shape)).astype(dt) for k, (shape, dt) in fields.items()}
    rows["mode"][:] = int(Mode.POLICY)
    out = io.BytesIO()
    labels = {"mode": {int(m): m.name for m in Mode}}
    w = McapRunWriter(
        out, fields, {"joint_names": [f"j{i}" for i in range(14)]}, start_unix_ns=0, labels=labels
    )
    t0 = time.thread_time()
    for i in range(ticks):
        w.write_tick(i, {k: v[i] for k, v in rows.items()}, time.time_ns())
        if i % 25 == 24:  # 0.5 s at 50 Hz: the durable flush of the log
            w.flush()
    cpu = time.thread_time() - t0
    w.finish({})
    npz = io.BytesIO()
    np.savez(npz, **rows)
    return {
        "cpu_ms_per_tick": cpu / ticks * 1e3,
        "mcap_bytes_per_tick": out.tell() / ticks,
        "npz_bytes_per_tick": npz.tell() / ticks,
    }


def bench_loop(path: Path, seconds: float, log_dir: Path | None) -> dict[str, float]:
    """The paced 50 Hz loop on the mock target."""
    pol = load_policy(path)
    cfg = RuntimeConfig(
        duration=seconds, start_mode="policy", safety=SafetyConfig(ramp_time=0.0, max_overruns=0)
    )
    rt = Runtime(
        pol, MockTarget("arms"), SampledCommands(pol.obs_manager.command_names), cfg, log_dir=log_dir
    )
    return rt.run().timing.summary()


def main() -> None:
    """Run both benchmarks and print the numbers."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ticks", type=int, default=2000, help="ticks for the writer benchmark")
    ap.add_argument("--loop-s", type=float, default=10.0, help="seconds per loop run")
    ap.add_argument("--rounds", type=int, default=2, help="alternating (no log, log) loop runs")
    args = ap.parse_args()
    print(f"{os.cpu_count()} CPUs; load average before: {os.getloadavg()}")
    w = bench_writer(args.ticks)
    print(
        f"[writer] {w['cpu_ms_per_tick']:.3f} ms thread CPU per tick; "
        f"MCAP {w['mcap_bytes_per_tick']:.0f} B/tick (zstd, chunk every 25 ticks), "
        f"NPZ {w['npz_bytes_per_tick']:.0f} B/tick"
    )
    from policy_factory import make_policy_file

    with tempfile.TemporaryDirectory() as tmp:
        policy = make_policy_file(Path(tmp) / "p.onnx")
        for r in range(args.rounds):
            for label, log_dir in (("no log", None), ("log", Path(tmp) / "runs")):
                s = bench_loop(policy, args.loop_s, log_dir)
                print(
                    f"[loop 50 Hz mock, {label}, round {r}] {s['ticks']} ticks: "
                    f"jitter p50 {s['jitter_p50_ms']:.3f} p99 {s['jitter_p99_ms']:.3f} "
                    f"max {s['jitter_max_ms']:.3f} ms; compute p99 {s['compute_p99_ms']:.3f} ms; "
                    f"overruns {s['overruns']}"
                )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
