"""The figure a ``bar-deploy`` reach run ends with: segment-end success rate and the final distance.

A segment is a stretch of POLICY ticks with one target pair (the commands' ``target_pos_left/right``); the
ticks of a moving target (a transition's glide, a stream's updates) make segments shorter than
``MIN_SEGMENT_S`` that are not scored. A scored segment succeeds when both fingertips are within
``SUCCESS_RADIUS`` (3 cm, the env's and ``bar-deploy eval``'s) of its targets on its last tick, as in the
evaluation. The final distance is each fingertip's distance to its target on the run's last POLICY tick.
Fingertips come from the measured joints the policy saw on the tick (``runtime.last_state.q``), so the
figure is the same on the sim, the mock and the real robot.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import RunFigure
from bar_policy.tasks.reach.shared import SUCCESS_RADIUS

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics

__all__ = ["MIN_SEGMENT_S", "ReachRunFigure"]

MIN_SEGMENT_S = 0.2
"""Shortest scored segment, s: a target held less long is a moving target, not a reach."""

_KEYS = ("target_pos_left", "target_pos_right")


class ReachRunFigure(RunFigure):
    """Segment-end success and final fingertip distances of one reach run."""

    def __init__(self, kinematics: Kinematics, control_dt: float, radius: float = SUCCESS_RADIUS) -> None:
        """``control_dt``: the policy period, s (segment lengths); ``radius``: success radius, m."""
        self.kin = kinematics
        self.min_ticks = max(1, round(MIN_SEGMENT_S / control_dt))
        self.radius = radius
        self.policy_ticks = 0
        self.segments = 0
        self.successes = 0
        self._target: np.ndarray | None = None
        self._ticks = 0
        self._dist = (math.nan, math.nan)

    def on_tick(self, k: int, t: float, rt: Any) -> None:
        """Score the tick's fingertips against its targets; close a segment when the targets change."""
        if not self.policy_ticking(rt) or not all(key in rt.last_commands for key in _KEYS):
            return
        target = np.concatenate([np.asarray(rt.last_commands[key], dtype=np.float64) for key in _KEYS])
        if self._target is not None and not np.array_equal(target, self._target):
            self._close()
        left, right = self.kin.fingertips(np.asarray(rt.last_state.q, dtype=np.float64))
        self._target = target
        self._ticks += 1
        self._dist = (float(np.linalg.norm(left - target[:3])), float(np.linalg.norm(right - target[3:])))
        self.policy_ticks += 1

    def _close(self) -> None:
        """End the current segment: scored when it lasted ``min_ticks`` or more."""
        if self._ticks >= self.min_ticks:
            self.segments += 1
            self.successes += int(max(self._dist) < self.radius)
        self._ticks = 0

    def _final(self) -> tuple[int, int]:
        """(segments, successes) with the open last segment scored as if it ended now."""
        last = int(self._ticks >= self.min_ticks)
        return self.segments + last, self.successes + int(last and max(self._dist) < self.radius)

    def line(self) -> str:
        """``reach: 3/4 segment ends within 3 cm (75.0 %); final distance left 0.6 cm, right 0.9 cm``."""
        if not self.policy_ticks:
            return "reach: no policy ticks"
        n, ok = self._final()
        rate = (
            f"{ok}/{n} segment ends within {self.radius * 100:g} cm ({100 * ok / n:.1f} %)"
            if n
            else (f"no segment held {MIN_SEGMENT_S:g} s or longer")
        )
        left, right = self._dist
        return f"reach: {rate}; final distance left {left * 100:.1f} cm, right {right * 100:.1f} cm"

    def to_dict(self) -> dict[str, Any]:
        """``{"segments", "successes", "success_rate", "final_dist_left_m", "final_dist_right_m", ...}``."""
        n, ok = self._final()
        return {
            "segments": n,
            "successes": ok,
            "success_rate": ok / n if n else None,
            "final_dist_left_m": self._dist[0],
            "final_dist_right_m": self._dist[1],
            "policy_ticks": self.policy_ticks,
            "success_radius_m": self.radius,
        }
