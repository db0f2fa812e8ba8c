"""CPU per tick of every thread of ``bar-deploy --target real --can-interface virtual`` (the emulated bus).

    python bench/tick_cpu.py --seconds 20 [--json out.json] [-- extra bar-deploy options]

Runs the deploy CLI in this process (the realtime in-process emulator, as ``bench/soak.py`` does in a
child) and reports, per control tick:

- the loop thread's CPU inside ``Runtime._tick`` (``time.thread_time``: state read, observation, ONNX,
  supervisor, command write, log append): mean / p50 / p99, ms;
- the CPU of every thread of the process over the loop (``time.pthread_getcpuclockid``: the loop thread
  with its pacing, the emulator's receiver and physics threads, the log writer, the CAN recorder), divided
  by the ticks run, ms;
- the wall-clock figures of the run's own summary (compute p50 / p99, late ticks).

CPU time is what one build costs, whatever else runs on the machine; wall-clock time on a shared host is
mostly the others' load. To compare two trees, run each with ``PYTHONPATH=<tree>`` from its root, in
turns (A, B, A, B, ...). The tick and the end of the loop are found by wrapping ``Runtime._tick`` and
``RunLoop._safe_end`` (the loop's safe ending), the only hooks this needs.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
import threading
import time
from pathlib import Path

import numpy as np

from bar_policy.deploy import cli, run_loop, runtime

ROOT = Path(__file__).resolve().parents[1]


def thread_cpu() -> dict[str, float]:
    """CPU time of every live thread of this process by thread name, s."""
    out = {}
    for t in threading.enumerate():
        with contextlib.suppress(OSError, TypeError, OverflowError):
            out[t.name] = time.clock_gettime(time.pthread_getcpuclockid(t.ident))
    return out


def measure(seconds: float, policy: str, extra: list[str]) -> dict:
    """One run of ``seconds``; the figures (module docstring)."""
    tick_cpu: list[float] = []
    marks: dict[str, dict[str, float]] = {}
    orig_tick, orig_end = runtime.Runtime._tick, run_loop.RunLoop._safe_end

    def tick(self, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202 - a transparent wrapper
        if not tick_cpu:
            marks["start"] = thread_cpu()
        c0 = time.thread_time()
        rec = orig_tick(self, *a, **k)
        tick_cpu.append(time.thread_time() - c0)
        return rec

    def safe_end(self, *a, **k):  # noqa: ANN001, ANN002, ANN003, ANN202
        marks.setdefault("end", thread_cpu())
        return orig_end(self, *a, **k)

    runtime.Runtime._tick, run_loop.RunLoop._safe_end = tick, safe_end
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            rc = cli.main(
                [
                    "--policy",
                    policy,
                    "--target",
                    "real",
                    "--can-interface",
                    "virtual",
                    "--duration",
                    f"{seconds:g}",
                    *extra,
                ]
            )
    finally:
        runtime.Runtime._tick, run_loop.RunLoop._safe_end = orig_tick, orig_end
    lines = out.getvalue().splitlines()
    n = len(tick_cpu)
    start, end = marks.get("start", {}), marks.get("end", {})
    ms = 1e3 * np.asarray(tick_cpu)
    compute = next((ln for ln in lines if ln.startswith("compute")), "")
    late = next((ln for ln in lines if ln.startswith("jitter")), "")
    wall = re.search(r"p50 ([\d.]+) ms\s+p99 ([\d.]+) ms", compute)
    late_n = re.search(r"(?:late ticks|overruns) (\d+)", late)
    threads = {k: 1e3 * (end[k] - start.get(k, 0.0)) / n for k in end} if n else {}
    return {
        "exit_status": rc,
        "ticks": n,
        "loop_tick_cpu_ms": {
            "mean": float(ms.mean()) if n else float("nan"),
            "p50": float(np.percentile(ms, 50)) if n else float("nan"),
            "p99": float(np.percentile(ms, 99)) if n else float("nan"),
        },
        "thread_cpu_ms_per_tick": threads,
        "process_cpu_ms_per_tick": sum(threads.values()),
        "compute_wall_p50_ms": float(wall.group(1)) if wall else float("nan"),
        "compute_wall_p99_ms": float(wall.group(2)) if wall else float("nan"),
        "late_ticks": int(late_n.group(1)) if late_n else None,
        "end_line": next((ln for ln in lines if ln.startswith("end:")), ""),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=20.0, help="run length (--duration), s")
    p.add_argument("--policy", default=str(ROOT / "checkpoints" / "lite_reach_arms.onnx"))
    p.add_argument("--json", type=Path, default=None, help="write the figures here too")
    p.add_argument("extra", nargs="*", help="more bar-deploy options (after --)")
    a = p.parse_args()
    r = measure(a.seconds, a.policy, a.extra)
    text = json.dumps(r, indent=1)
    print(text)
    if a.json:
        a.json.write_text(text)
    return 0 if r["exit_status"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
