"""bench/soak.py's host-stall watcher: it sees a stall of its own process, and the summary's arithmetic.

A stall is made by stopping the watcher (SIGSTOP) for a measured time: the watcher cannot run then, so its
wake-up before the stop and the one after it are at least that far apart, and the gap spans the moment
the process was continued.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from script_modules import load_bench

BENCH = Path(__file__).resolve().parents[1] / "bench"


soak = load_bench("soak")


def _wait_for(predicate, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs POSIX job-control signals")
def test_the_watcher_records_a_stall_of_its_process(tmp_path):
    out = tmp_path / "stalls.txt"
    proc = soak.start_stall_watcher(out)
    try:
        time.sleep(0.5)  # past the interpreter's start-up (a slow start is not the stall under test)
        t_stop = time.time()
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.2)
        t_cont = time.time()
        os.kill(proc.pid, signal.SIGCONT)

        def spanning() -> list[tuple[float, float]]:
            return [(a, b) for a, b in soak.read_stalls(out) if a <= t_cont <= b]

        # Other gaps (a loaded host) may come before or after it; the one spanning t_cont must come.
        assert _wait_for(lambda: spanning(), 10.0), soak.read_stalls(out)
    finally:
        proc.kill()
        proc.wait()
    spanning = spanning()
    assert len(spanning) == 1, spanning
    a, b = spanning[0]
    # The process was stopped from before t_stop's kill returned until after t_cont: its last wake-up
    # before the stop is <= the stop's delivery (<= 5 ms after t_stop on a loaded host), its next one is
    # after t_cont, so the gap is at least t_cont - t_stop - 5 ms (>= 195 ms).
    assert b - a >= (t_cont - t_stop) - 0.005
    assert a <= t_stop + 0.005


def test_stall_summary_counts_and_places_the_long_gaps():
    t0 = 100.0
    gaps = [(100.5, 100.506), (101.0, 101.025), (102.0, 102.060)]  # 6, 25 and 60 ms
    s = soak.stall_summary(gaps, t0)
    assert s["stall_gaps_over_5ms"] == 3
    assert s["stall_gaps_over_20ms"] == 2  # 25 and 60 ms
    assert s["stall_gaps_over_50ms"] == 1  # 60 ms
    # 1e3 * (102.060 - 102.0) is 60 ms to ~1e-11 ms (float spacing near 102 s is 1.4e-14 s).
    assert s["stall_max_ms"] == pytest.approx(60.0, abs=1e-6)
    assert s["stalls_over_20ms_at"] == [(1.0, 25.0), (2.0, 60.0)]
    assert soak.stall_summary([], t0)["stall_max_ms"] == 0.0


def test_read_stalls_skips_a_line_cut_by_the_kill(tmp_path):
    path = tmp_path / "stalls.txt"
    path.write_text("1.000000 1.030000\n2.000000 2.0")  # the second line was cut mid-write
    assert soak.read_stalls(path) == [(1.0, 1.03)]
    path.write_text("")
    assert soak.read_stalls(path) == []


def _priority_under_fifo(rt_priority: int | None) -> int | None:
    """``watcher_priority`` computed in a child that runs under SCHED_FIFO 50 (as ``chrt -f 50`` runs it)."""
    import subprocess

    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('soak', {str(BENCH / 'soak.py')!r})\n"
        "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m)\n"
        f"print(m.watcher_priority({rt_priority!r}))\n"
    )

    def fifo_50() -> None:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))

    try:
        out = subprocess.run(
            [sys.executable, "-c", code], preexec_fn=fifo_50, capture_output=True, text=True, timeout=120
        )
    except (PermissionError, subprocess.SubprocessError) as e:
        pytest.skip(f"SCHED_FIFO not permitted here: {e}")
    if out.returncode != 0:
        pytest.skip(f"SCHED_FIFO not permitted here: {out.stderr.strip()[-200:]}")
    text = out.stdout.strip().splitlines()[-1]
    return None if text == "None" else int(text)


def test_the_watcher_runs_above_the_soak_and_its_loop():
    if os.sched_getscheduler(0) not in (os.SCHED_FIFO, os.SCHED_RR):
        assert soak.watcher_priority(60) is None  # a soak under the normal scheduler: a normal watcher
    assert _priority_under_fifo(60) == 61  # the loop at 60 above the soak's 50: one above the loop
    assert _priority_under_fifo(None) == 51  # no loop priority: one above the soak's own 50
    assert _priority_under_fifo(99) == 99  # capped at the highest SCHED_FIFO priority


def test_slow_ticks_are_matched_to_the_stalls_around_them():
    # Ticks every 20 ms from t = 1000 s; ticks 2 and 5 slow (45 and 60 ms; the threshold is 40 ms).
    tick_unix = 1000.0 + 0.02 * np.arange(8)
    compute = np.array([0.005, 0.005, 0.045, 0.005, 0.005, 0.060, 0.005, 0.005])
    # Tick 2 spans [1000.04, 1000.085]: a gap at [1000.30, 1000.33] starts 0.215 s after its end, outside
    # the 0.2 s window; tick 5 spans [1000.10, 1000.16]: the same gap starts 0.14 s after it, inside.
    gaps = [(1000.30, 1000.33)]
    r = soak.slow_ticks_vs_stalls(tick_unix, compute, gaps, end_unix=None)
    assert r == {"slow_ticks": 2, "slow_ticks_with_a_stall": 1, "stall_before_end_ms": None}
    # A fault ending at 1000.5: gaps from 999.5 on count; the 30 ms one and a 70 ms one at 999.6.
    gaps_f = [(999.2, 999.4), (999.6, 999.67), (1000.30, 1000.33)]  # the first ends before 999.5
    r = soak.slow_ticks_vs_stalls(tick_unix, compute, gaps_f, end_unix=1000.5)
    assert r["stall_before_end_ms"] == pytest.approx(70.0, abs=1e-6)  # (999.67 - 999.6) s to ~1e-10 ms
    assert soak.slow_ticks_vs_stalls(tick_unix, compute, [], end_unix=1000.5)["stall_before_end_ms"] == 0.0
