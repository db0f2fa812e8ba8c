"""Loop timing: absolute-deadline sleeping, per-tick timing statistics, real-time scheduling of the loop.

``sleep_until`` sleeps, then busy-waits the last ``spin_s`` (``time.sleep`` overshoots by tens of
microseconds to milliseconds); ``Pacer`` keeps the loop on its deadline grid and collects the per-tick
times; ``TimingStats`` summarises a run's compute, inference and jitter;
``RealtimePriority`` runs the calling thread under SCHED_FIFO for the length of a block (Linux, needs
CAP_SYS_NICE; logged and skipped when not permitted); ``FrozenHeap`` keeps the start-up's objects out of the
garbage collector's scans for the length of a block.
"""

from __future__ import annotations

import gc
import logging
import math
import os
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["FrozenHeap", "Pacer", "RealtimePriority", "TimingStats", "sleep_until"]

log = logging.getLogger("bar_policy.deploy.runtime")


def sleep_until(deadline: float, spin_s: float = 0.0003) -> None:
    """Wait until ``time.perf_counter() >= deadline``: sleep, then busy-wait the last ``spin_s`` seconds."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > spin_s:
            time.sleep(remaining - spin_s)


@dataclass(frozen=True)
class TimingStats:
    """Per-tick timing of a run. Arrays have shape (ticks,), seconds."""

    compute: np.ndarray
    """Host compute per tick: state read -> observation -> ONNX -> command written."""
    infer: np.ndarray
    """ONNX inference alone (NaN in ticks without inference)."""
    jitter: np.ndarray
    """Tick start minus its deadline (0 for an unpaced synchronous target)."""
    overruns: int
    """Ticks that ran late: ended after the next deadline."""
    wall: float
    """Wall-clock duration of the loop, s."""
    target_time: float
    """Target-clock duration, s."""
    paced: bool
    """True when ticks were paced against the wall clock."""
    skipped: int = 0
    """Deadlines skipped after late ticks (the ticks that did not run in a paced run's duration)."""

    def summary(self) -> dict[str, float]:
        """p50 / p99 / max in ms, counts, rates."""

        def pct(x: np.ndarray, p: float) -> float:
            x = x[np.isfinite(x)]
            return float(np.percentile(x, p) * 1e3) if x.size else float("nan")

        ticks = int(self.compute.size)
        out = {
            "ticks": ticks,
            "compute_p50_ms": pct(self.compute, 50),
            "compute_p99_ms": pct(self.compute, 99),
            "compute_max_ms": pct(self.compute, 100),
            "infer_p50_ms": pct(self.infer, 50),
            "infer_p99_ms": pct(self.infer, 99),
            "overruns": self.overruns,
            "skipped": self.skipped,
            "wall_s": self.wall,
            "target_s": self.target_time,
            "rate_hz": ticks / self.wall if self.wall > 0 else float("nan"),
            "realtime_factor": self.target_time / self.wall if self.wall > 0 else float("nan"),
        }
        if self.paced:
            out |= {
                "jitter_p50_ms": pct(np.abs(self.jitter), 50),
                "jitter_p99_ms": pct(np.abs(self.jitter), 99),
                "jitter_max_ms": pct(np.abs(self.jitter), 100),
            }
        return out

    def format(self) -> str:
        """Human-readable table."""
        s = self.summary()
        lines = [
            f"ticks {s['ticks']}  wall {s['wall_s']:.3f} s  target {s['target_s']:.3f} s  "
            f"rate {s['rate_hz']:.1f} Hz  real-time factor {s['realtime_factor']:.1f}x",
            f"compute (state->obs->ONNX->command) p50 {s['compute_p50_ms']:.3f} ms  "
            f"p99 {s['compute_p99_ms']:.3f} ms  max {s['compute_max_ms']:.3f} ms",
            f"ONNX inference p50 {s['infer_p50_ms']:.3f} ms  p99 {s['infer_p99_ms']:.3f} ms",
        ]
        if self.paced:
            lines.append(
                f"jitter p50 {s['jitter_p50_ms']:.3f} ms  p99 {s['jitter_p99_ms']:.3f} ms  "
                f"max {s['jitter_max_ms']:.3f} ms  late ticks {s['overruns']} (ended after the next "
                f"deadline; {s['skipped']} deadlines skipped)"
            )
        else:
            lines.append("unpaced synchronous target: no jitter, no overruns")
        return "\n".join(lines)


class RealtimePriority:
    """SCHED_FIFO for the calling thread while inside the block (restored after); logs when not permitted."""

    def __init__(self, priority: int | None) -> None:
        self.priority = priority
        self._previous: tuple[int, int] | None = None

    def __enter__(self) -> RealtimePriority:
        if self.priority is None:
            return self
        try:
            prev = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
            self._previous = prev
            log.info("control loop runs under SCHED_FIFO priority %d", self.priority)
        except (AttributeError, OSError) as e:
            log.warning(
                "cannot use SCHED_FIFO priority %d (%s); running with the normal scheduler", self.priority, e
            )
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            policy, prio = self._previous
            os.sched_setscheduler(0, policy, os.sched_param(prio))


class FrozenHeap:
    """The objects alive at the block's start left out of every garbage collection inside it.

    Python's full collection scans every tracked object; after start-up (MuJoCo, onnxruntime, numpy, the
    models, the song) one took 15-21 ms inside a piano tick on the 2-core CPU, a whole 20 ms control period
    (``bench/piano_tick.py``'s max). On entry ``gc.freeze()``: what is alive moves to a permanent generation
    no collection scans, so the loop's collections see only what the loop made; on exit ``gc.unfreeze()``.
    Collection stays on: the loop's own garbage is still freed. No collection first: the loop starts with
    the motors enabled and their watchdog armed, and a full collection of a large heap (a test process's)
    took longer than the watchdog; start-up garbage frozen with the rest is only memory, freed after. A heap
    already frozen on entry (a caller's own freeze, an outer block) stays frozen on exit.
    """

    def __init__(self) -> None:
        self._owner = False

    def __enter__(self) -> FrozenHeap:
        self._owner = gc.get_freeze_count() == 0
        gc.freeze()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._owner:
            gc.unfreeze()


class Pacer:
    """The loop's clock: absolute deadlines ``t0 + k * dt`` (no drift), overruns, per-tick statistics.

    A paced loop sleeps until each deadline (``sleep_until``); a tick that ends after the next deadline is
    an overrun (a tick that ran late), and the missed deadlines are skipped (the grid keeps its phase):
    ``index`` counts the deadlines passed, run or skipped, so ``index * dt`` is the wall-clock time of the
    next deadline since the start. An unpaced loop (a synchronous target) never waits and has no jitter or
    overruns; its ``index`` counts the ticks.
    """

    def __init__(
        self, dt: float, paced: bool, spin_s: float = 0.0003, n_deadlines: int | None = None
    ) -> None:
        """Args: control period (s), whether to pace, busy-wait margin (s), run length in deadlines.

        ``n_deadlines`` None is open-ended. A late last tick passes deadlines after the run's end; those are
        not the run's and are not counted as skipped.
        """
        self.dt = dt
        self.paced = paced
        self.spin_s = spin_s
        self.n_deadlines = n_deadlines
        self.wall0 = time.perf_counter()
        """Wall clock of the loop's start, s (``time.perf_counter``)."""
        self.index = 0
        """The next deadline's number: its time is ``wall0 + index * dt``."""
        self.compute: list[float] = []
        self.infer: list[float] = []
        self.jitter: list[float] = []
        self.overruns = 0
        self.skipped = 0
        """Deadlines skipped after overruns (ticks that never ran)."""

    @property
    def elapsed(self) -> float:
        """Time of the next deadline since the start, s (wall clock when paced, else ticks x dt)."""
        return self.index * self.dt

    def wait(self) -> tuple[float, float]:
        """Wait for the next deadline; returns (tick start, lateness = start - deadline; 0 unpaced), s."""
        deadline = self.wall0 + self.index * self.dt
        if self.paced:
            sleep_until(deadline, self.spin_s)
        start = time.perf_counter()
        return start, (start - deadline if self.paced else 0.0)

    def tick_done(self, lateness: float, compute: float, infer: float) -> bool:
        """Record a tick that took ``compute`` s (``infer`` in ONNX); returns True when it overran."""
        self.compute.append(compute)
        self.infer.append(infer)
        self.jitter.append(lateness)
        self.index += 1
        if not self.paced:
            return False
        end = time.perf_counter()
        deadline = self.wall0 + self.index * self.dt
        if end <= deadline:
            return False
        self.overruns += 1
        skip = math.ceil((end - deadline) / self.dt)  # skip the missed deadlines, keep the grid
        if self.n_deadlines is not None:  # only the run's own deadlines count as skipped
            skip = max(min(skip, self.n_deadlines - self.index), 0)
        self.index += skip
        self.skipped += skip
        return True

    def stats(self, target_time: float) -> TimingStats:
        """The run's statistics (the loop's wall time ends now)."""
        return TimingStats(
            compute=np.asarray(self.compute),
            infer=np.asarray(self.infer),
            jitter=np.asarray(self.jitter),
            overruns=self.overruns,
            wall=time.perf_counter() - self.wall0,
            target_time=target_time,
            paced=self.paced,
            skipped=self.skipped,
        )
