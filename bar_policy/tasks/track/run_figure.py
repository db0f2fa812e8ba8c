"""The figure a ``bar-deploy`` track run ends with: its tracking errors over the POLICY ticks.

Each POLICY tick, the measured joints the policy saw (``runtime.last_state.q``) against the reference frame
it was tracking (``MotionReference.target_q``'s: the frame after the source's current one, the held last
frame at the end), with the evaluation's per-step metrics (``evaluate.step_errors``): mean absolute joint
error (rad), tracked-body and fingertip position errors (m), the share of ticks within the success bound.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from bar_policy.tasks.interfaces import RunFigure
from bar_policy.tasks.track.reference import MotionReference

if TYPE_CHECKING:
    from bar_policy.robot.kinematics import Kinematics

__all__ = ["TrackRunFigure"]


class TrackRunFigure(RunFigure):
    """Tracking errors of one track run, means over its POLICY ticks."""

    def __init__(self, reference: MotionReference, kinematics: Kinematics) -> None:
        from bar_policy.tasks.track.evaluate import METRICS

        self.reference = reference
        self.kin = kinematics
        self.sums = dict.fromkeys(METRICS, 0.0)
        self.policy_ticks = 0

    def on_tick(self, k: int, t: float, rt: Any) -> None:
        """Add the tick's errors against the reference frame the policy was tracking."""
        if not self.policy_ticking(rt):
            return
        from bar_policy.tasks.track.evaluate import step_errors

        ref = self.reference
        frame = min(int(ref.record()["ref_frame"]) + 1, ref.last)
        q = np.asarray(rt.last_state.q, dtype=np.float64)
        for key, value in step_errors(self.kin, q, ref.table, frame).items():
            self.sums[key] += value
        self.policy_ticks += 1

    def mean(self, key: str) -> float:
        """Mean of a metric over the POLICY ticks (NaN without any)."""
        return self.sums[key] / self.policy_ticks if self.policy_ticks else float("nan")

    def line(self) -> str:
        """``track: mean joint error 0.0213 rad, tracked-body position error 1.20 cm, ...``."""
        if not self.policy_ticks:
            return "track: no policy ticks"
        return (
            f"track ({self.reference.clip.name}): mean joint error {self.mean('joint_error'):.4f} rad, "
            f"tracked-body position error {100 * self.mean('body_pos_error'):.2f} cm, fingertip error "
            f"{100 * self.mean('fingertip_error'):.2f} cm, success {100 * self.mean('success'):.1f} % of "
            f"{self.policy_ticks} policy ticks"
        )

    def to_dict(self) -> dict[str, Any]:
        """Means in rad and m, the success share (0..1), the tick count."""
        return {
            "joint_error_rad": self.mean("joint_error"),
            "body_pos_error_m": self.mean("body_pos_error"),
            "fingertip_error_m": self.mean("fingertip_error"),
            "success": self.mean("success"),
            "policy_ticks": self.policy_ticks,
        }
