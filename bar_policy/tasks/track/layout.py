"""The motion tracking observation layout (``lite_track_<mode>``), frozen by ``obs/schemas/``'s goldens."""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema
from bar_policy.obs.robot_layout import robot_schema, state_terms, term
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.track.shared import TRACK_BODY_NAMES, TRACK_LOOKAHEAD_STEPS, track_default_pose

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the motion tracking layout (``bar_policy.tasks.track.shared``).

    The reference at the next ``TRACK_LOOKAHEAD_STEPS`` frames (joint positions, then Humanoid Control's
    ``motion_body_pos_b`` / ``motion_body_ori_b``), then the robot's own state in Humanoid Control's order.
    """
    n, k, b = load_robot(mode).num_joints, TRACK_LOOKAHEAD_STEPS, len(TRACK_BODY_NAMES)
    reference = (
        term("motion_joint_pos", k * n),
        term("motion_body_pos_b", k * b * 3),
        term("motion_body_ori_b", k * b * 6),
    )
    return robot_schema(
        f"lite_track_{mode}",
        1,
        mode,
        (*reference, *state_terms(n)),
        default_joint_pos=track_default_pose(mode),
        body_names=TRACK_BODY_NAMES,
        lookahead_steps=k,
    )
