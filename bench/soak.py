"""Soak benchmark: the real target on the Robstride emulator for a long run with the CPU loaded.

    python bench/soak.py --minutes 30 --json soak.json --markdown soak.md

It starts ``--load-procs`` busy processes (a pure-Python spin each: the "second process" that competes
for the 2 cores), then runs the real deploy command as a user would,
``bar-deploy --policy P --target real --can-interface virtual --duration S --log DIR`` (python-can's
``virtual`` bus to the in-process emulator in realtime mode: the CAN codec, the driver, the watchdog, the
supervisor and both logs in the loop), and stops the load when the run ends. From the run directory it
reports:

- timing: ticks, rate, compute p50 / p99 / max, jitter p99 / max, overruns (``run.json``'s ``timing``);
  the worst jitter p99 over any minute (from ``log.npz``'s per-tick ``jitter``);
- faults: ``fault_count``, the end reason, the safe stop's outcome, the exit status;
- log completeness: ticks expected (duration / dt deadlines of wall clock, less those skipped after late
  ticks), ticks in ``log.npz``, ``/joint_state_json`` messages in
  ``run.mcap`` (``read_mcap_log``) and whether the ``mcap`` library's indexed reader opens it;
- host stalls: an idle watcher process pinned to each CPU (``STALL_WATCHER``; under ``chrt``, SCHED_FIFO
  one above the run's loop and threads, ``watcher_priority``) wakes every 1 ms during the run and records
  each wake-up later than 5 ms: the counts over 20 and 50 ms, the longest, and when the long ones came (s
  after the soak's start); the slow ticks that came with one, and the longest in the second before a
  fault. The emulator runs in the deploy process, so a stall of the machine (a virtual machine's CPU taken
  away by its host, a kernel stall) delays its replies as it delays the loop: a "no reply within 50 ms"
  fault with stalls of tens of ms in a watcher at the same time is the machine's, not the code's (a real
  motor answers during a host stall, and ``collect_round`` counts the replies queued by the deadline).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bar_policy.deploy.log.mcap_read import read_mcap_log
from bar_policy.deploy.log.mcap_schema import MCAP_FILE
from bar_policy.deploy.log.read import load_log

ROOT = Path(__file__).resolve().parents[1]


def _as_ordinary_load() -> None:
    """In the busy child: the normal scheduler (not a SCHED_FIFO the soak may run under) on CPU 0."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.sched_setaffinity(0, {0})


def _spin() -> subprocess.Popen:
    """One busy process (pure Python) on one core, under the normal scheduler whatever the soak runs under."""
    return subprocess.Popen([sys.executable, "-c", "while True:\n    pass"], preexec_fn=_as_ordinary_load)


STALL_WATCHER = """
import sys, time
unix = time.time() - time.perf_counter()
last = time.perf_counter()
while True:
    time.sleep(0.001)
    now = time.perf_counter()
    if now - last > 0.005:
        sys.stdout.write(f"{unix + last:.6f} {unix + now:.6f}\\n")
        sys.stdout.flush()
    last = now
"""
"""The watcher's program: one line ``start end`` per wake-up gap over 5 ms, s since the epoch (measured
with ``time.perf_counter``, placed on the wall clock once at its start, like the run log's
``started_unix``)."""


def watcher_priority(rt_priority: int | None) -> int | None:
    """The watcher's SCHED_FIFO priority: above the run's loop and threads when the soak runs real-time.

    Under ``chrt`` the deploy process's threads run at the soak's priority and its loop at
    ``rt_priority``: one above both (at most 99), so that only the machine (the kernel, the hypervisor, the
    real-time throttle) can delay the watcher, not the run it watches. None (the normal scheduler) when the
    soak itself is not real-time.
    """
    if os.sched_getscheduler(0) not in (os.SCHED_FIFO, os.SCHED_RR):
        return None
    return min(99, max(os.sched_getparam(0).sched_priority, rt_priority or 0) + 1)


def start_stall_watcher(out: Path, priority: int | None = None, cpu: int | None = None) -> subprocess.Popen:
    """Start the idle watcher (``STALL_WATCHER``) writing its gaps to ``out``; stop it with ``kill``.

    ``priority``: SCHED_FIFO at this priority (``watcher_priority``); None: the soak's own scheduler.
    ``cpu``: pinned to this CPU (the soak runs one per CPU: a virtual machine's CPU taken away by its host
    stops the threads on it, and an unpinned watcher would just run on the other); None: not pinned.
    """

    def as_watcher() -> None:
        if priority is not None:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})

    with out.open("w") as f:
        return subprocess.Popen([sys.executable, "-c", STALL_WATCHER], stdout=f, preexec_fn=as_watcher)


def read_stalls(path: Path) -> list[tuple[float, float]]:
    """The watcher's gaps: (start, end) pairs, s since the epoch.

    Only whole lines count: a last line without its newline was cut by the kill mid-write.
    """
    gaps = []
    for line in path.read_text().split("\n")[:-1]:
        a, b = line.split()
        gaps.append((float(a), float(b)))
    return gaps


def stall_summary(gaps: list[tuple[float, float]], t0: float) -> dict:
    """Counts of gaps over 5, 20 and 50 ms, the longest (ms), and the gaps over 20 ms as (start, length).

    ``t0``: the soak's start, s since the epoch; a gap's start is given in s after it (the run's start-up
    comes first: about 1 s).
    """
    ms = [1e3 * (b - a) for a, b in gaps]
    long = [(round(a - t0, 3), round(1e3 * (b - a), 1)) for a, b in gaps if 1e3 * (b - a) > 20.0]
    return {
        "stall_gaps_over_5ms": len(ms),
        "stall_gaps_over_20ms": sum(m > 20.0 for m in ms),
        "stall_gaps_over_50ms": sum(m > 50.0 for m in ms),
        "stall_max_ms": max(ms, default=0.0),
        "stalls_over_20ms_at": long,
    }


SLOW_TICK_MS = 40.0
"""A tick slower than this (compute, ms) is checked against the watcher's gaps (``slow_ticks_vs_stalls``)."""
STALL_WINDOW_S = 0.2
"""Slack around a slow tick within which a watcher gap counts as its stall, s (the tick times are placed on
the wall clock through the log's ``started_unix``, taken just before the loop's first deadline)."""


def slow_ticks_vs_stalls(
    tick_unix: np.ndarray, compute_s: np.ndarray, gaps: list[tuple[float, float]], end_unix: float | None
) -> dict:
    """Which slow ticks came with a stall of the machine, and the stall before a fault's end.

    Args:
        tick_unix: each tick's start, s since the epoch (ticks,).
        compute_s: each tick's compute, s (ticks,).
        gaps: the watcher's gaps (``read_stalls``).
        end_unix: when the loop ended on a fault (the last tick's end), s since the epoch; None: no fault.

    Returns:
        ``slow_ticks`` (compute over ``SLOW_TICK_MS``), ``slow_ticks_with_a_stall`` (a gap overlapping the
        tick widened by ``STALL_WINDOW_S`` each side), and ``stall_before_end_ms``: the longest gap within
        the second before ``end_unix`` (to ``STALL_WINDOW_S`` after it; None without a fault, 0.0 without a
        gap).
    """
    slow = np.flatnonzero(1e3 * np.asarray(compute_s) > SLOW_TICK_MS)
    with_stall = 0
    for k in slow:
        lo = float(tick_unix[k]) - STALL_WINDOW_S
        hi = float(tick_unix[k] + compute_s[k]) + STALL_WINDOW_S
        with_stall += any(a < hi and b > lo for a, b in gaps)
    before = None
    if end_unix is not None:
        near = [1e3 * (b - a) for a, b in gaps if a < end_unix + STALL_WINDOW_S and b > end_unix - 1.0]
        before = max(near, default=0.0)
    return {
        "slow_ticks": int(slow.size),
        "slow_ticks_with_a_stall": with_stall,
        "stall_before_end_ms": before,
    }


def _indexed_ok(path: Path) -> bool:
    """Whether the ``mcap`` library's indexed reader reads the file's summary."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            return make_reader(f).get_summary() is not None
    except Exception:
        return False


def soak(policy: str, minutes: float, load_procs: int, log_dir: Path, rt_priority: int | None = None) -> dict:
    """Run the soak; the figures (see the module docstring).

    ``rt_priority``: the run's ``--rt-priority`` (SCHED_FIFO for the control loop, as a robot computer runs
    it); None runs the loop under the normal scheduler.
    """
    duration = 60.0 * minutes
    load = [_spin() for _ in range(load_procs)]
    cpus = sorted(os.sched_getaffinity(0))
    stall_files = [log_dir / f"stalls_cpu{c}.txt" for c in cpus]
    t0 = time.perf_counter()
    t0_unix = time.time()
    prio = watcher_priority(rt_priority)
    watchers = [start_stall_watcher(f, prio, c) for f, c in zip(stall_files, cpus, strict=True)]
    try:
        cmd = [
            sys.executable,
            "-m",
            "bar_policy.deploy.cli",
            "--policy",
            policy,
            "--target",
            "real",
            "--can-interface",
            "virtual",
            "--duration",
            f"{duration:g}",
            "--log",
            str(log_dir),
        ]
        if rt_priority is not None:
            cmd += ["--rt-priority", str(rt_priority)]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    finally:
        for p in (*load, *watchers):
            p.kill()
            p.wait()
    wall = time.perf_counter() - t0
    run_dir = max((p for p in log_dir.iterdir() if p.is_dir()), key=lambda p: p.stat().st_mtime)
    meta = json.loads((run_dir / "run.json").read_text())
    arrays, _ = load_log(run_dir)
    dt = float(meta["runtime_config"]["control_dt"])
    jitter = np.abs(np.asarray(arrays["jitter"], dtype=np.float64))
    per_min = max(1, round(60.0 / dt))
    minute_p99 = [
        1000.0 * float(np.nanpercentile(jitter[i : i + per_min], 99)) for i in range(0, jitter.size, per_min)
    ]
    mcap = read_mcap_log(run_dir / MCAP_FILE)
    mcap_ticks = int(np.asarray(mcap.arrays["t"]).size)
    timing = meta["timing"]
    gaps = sorted(g for f in stall_files for g in read_stalls(f))
    tick_unix = float(meta["started_unix"]) + np.asarray(arrays["wall"], dtype=np.float64)
    compute_s = np.asarray(arrays["compute"], dtype=np.float64)
    faulted = meta["fault_count"] > 0 and tick_unix.size > 0
    end_unix = float(tick_unix[-1] + compute_s[-1]) if faulted else None
    return {
        "policy": policy,
        "minutes": minutes,
        "load_procs": load_procs,
        "rt_priority": rt_priority,
        "exit_status": proc.returncode,
        "end_line": next((ln for ln in proc.stdout.splitlines() if ln.startswith("end:")), ""),
        "wall_s": wall,
        "timing": timing,
        "worst_minute_jitter_p99_ms": max(minute_p99) if minute_p99 else float("nan"),
        "overrun_ticks_in_log": int(np.count_nonzero(arrays["overrun"])),
        "fault_count": meta["fault_count"],
        "end_reason": meta["end_reason"],
        "safe_stop": meta["safe_stop"],
        "ticks_expected": round(duration / dt) - int(timing.get("skipped", 0)),  # --duration is wall clock
        "ticks_run_json": meta["ticks"],
        "ticks_log_npz": int(arrays["t"].size),
        "ticks_mcap": mcap_ticks,
        "mcap_complete": bool(mcap.complete),
        "mcap_indexed_reader_ok": _indexed_ok(run_dir / MCAP_FILE),
        **stall_summary(gaps, t0_unix),
        **slow_ticks_vs_stalls(tick_unix, compute_s, gaps, end_unix),
        "run_dir": str(run_dir),
        "loadavg": os.getloadavg(),
        "cpus": os.cpu_count(),
    }


def markdown(r: dict) -> str:
    """The figures as a table."""
    t = r["timing"]
    rows = [
        (
            "run",
            f"{r['minutes']:g} min, real target on the emulator (virtual CAN, realtime), "
            f"{r['load_procs']} busy process(es) on {r['cpus']} CPUs, loop priority "
            f"{'SCHED_FIFO ' + str(r['rt_priority']) if r.get('rt_priority') else 'normal'}",
        ),
        ("exit status / end", f"{r['exit_status']} / {r['end_reason']}"),
        ("faults", str(r["fault_count"])),
        ("safe stop", r["safe_stop"]),
        (
            "ticks expected / run.json / log.npz / MCAP",
            f"{r['ticks_expected']} / {r['ticks_run_json']} / {r['ticks_log_npz']} / {r['ticks_mcap']}",
        ),
        ("MCAP opens in the indexed reader", str(r["mcap_indexed_reader_ok"])),
        ("rate", f"{t['rate_hz']:.2f} Hz"),
        (
            "compute p50 / p99 / max",
            f"{t['compute_p50_ms']:.2f} / {t['compute_p99_ms']:.2f} / {t['compute_max_ms']:.2f} ms",
        ),
        (
            "jitter p99 / max (whole run)",
            f"{t.get('jitter_p99_ms', float('nan')):.3f} / {t.get('jitter_max_ms', float('nan')):.3f} ms",
        ),
        ("jitter p99, worst minute", f"{r['worst_minute_jitter_p99_ms']:.3f} ms"),
        ("overruns", f"{t['overruns']} (ticks flagged in the log: {r['overrun_ticks_in_log']})"),
        (
            "host stalls (idle watcher's wake-ups late by > 20 / > 50 ms; longest)",
            f"{r['stall_gaps_over_20ms']} / {r['stall_gaps_over_50ms']}; {r['stall_max_ms']:.1f} ms",
        ),
        (
            f"ticks slower than {SLOW_TICK_MS:g} ms / with a host stall",
            f"{r['slow_ticks']} / {r['slow_ticks_with_a_stall']}",
        ),
        (
            "longest host stall in the second before a fault",
            "-" if r["stall_before_end_ms"] is None else f"{r['stall_before_end_ms']:.1f} ms",
        ),
    ]
    return "\n".join(["| quantity | value |", "|---|---|", *(f"| {a} | {b} |" for a, b in rows)])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--policy", default=str(ROOT / "checkpoints" / "lite_reach_arms.onnx"))
    p.add_argument("--minutes", type=float, default=30.0, help="run length, min")
    p.add_argument("--load-procs", type=int, default=1, help="busy processes competing for the CPU")
    p.add_argument("--log", type=Path, default=None, help="run log directory (default: a temporary one)")
    p.add_argument(
        "--rt-priority",
        type=int,
        default=None,
        metavar="1-99",
        help="the run's --rt-priority (SCHED_FIFO control loop; root or CAP_SYS_NICE)",
    )
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--markdown", type=Path, default=None)
    a = p.parse_args()
    log_dir = a.log or Path(tempfile.mkdtemp(prefix="soak-"))
    log_dir.mkdir(parents=True, exist_ok=True)
    r = soak(a.policy, a.minutes, a.load_procs, log_dir, a.rt_priority)
    md = markdown(r)
    print(md)
    if a.json:
        a.json.write_text(json.dumps(r, indent=2, default=float))
    if a.markdown:
        a.markdown.write_text(md + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
