"""The motion tracking observation layout (``lite_track_<mode>``), frozen by ``obs/schemas/``'s goldens."""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema, ObsTerm
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.track.shared import TRACK_BODY_NAMES, TRACK_LOOKAHEAD_STEPS, track_default_pose

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the motion tracking layout (``bar_policy.tasks.track.shared``).

    The reference at the next ``TRACK_LOOKAHEAD_STEPS`` frames (joint positions, then Humanoid Control's
    ``motion_body_pos_b`` / ``motion_body_ori_b``), then the robot's own state in Humanoid Control's order.
    """
    robot = load_robot(mode)
    n, k, b = robot.num_joints, TRACK_LOOKAHEAD_STEPS, len(TRACK_BODY_NAMES)
    return ObservationSchema(
        name=f"lite_track_{mode}",
        version=1,
        robot=robot.robot,
        mode=mode,
        joint_names=robot.joint_names,
        action_joint_names=robot.joint_names,
        default_joint_pos=tuple(float(x) for x in track_default_pose(mode)),
        terms=(
            ObsTerm(name="motion_joint_pos", size=k * n, scale=1.0, clip=100.0),
            ObsTerm(name="motion_body_pos_b", size=k * b * 3, scale=1.0, clip=100.0),
            ObsTerm(name="motion_body_ori_b", size=k * b * 6, scale=1.0, clip=100.0),
            ObsTerm(name="joint_pos", size=n, scale=1.0, clip=100.0),
            ObsTerm(name="joint_vel", size=n, scale=0.1, clip=100.0),
            ObsTerm(name="actions", size=n, scale=1.0, clip=100.0),
        ),
        body_names=TRACK_BODY_NAMES,
        lookahead_steps=k,
    )
