"""The reach observation layout (``lite_reach_<mode>``), frozen by the golden files in ``obs/schemas/``."""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema, ObsTerm
from bar_policy.robot.constants import load_robot

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the bimanual reach layout: q, dq, the last action, both fingertips, both targets."""
    robot = load_robot(mode)
    n = robot.num_joints
    return ObservationSchema(
        name=f"lite_reach_{mode}",
        version=1,
        robot=robot.robot,
        mode=mode,
        joint_names=robot.joint_names,
        action_joint_names=robot.joint_names,
        default_joint_pos=tuple(float(x) for x in robot.pose("piano_ready")),
        terms=(
            ObsTerm(name="joint_pos", size=n, scale=1.0, clip=100.0),
            ObsTerm(name="joint_vel", size=n, scale=0.1, clip=100.0),
            ObsTerm(name="actions", size=n, scale=1.0, clip=100.0),
            ObsTerm(name="fingertip_pos_left", size=3, scale=1.0, clip=100.0),
            ObsTerm(name="fingertip_pos_right", size=3, scale=1.0, clip=100.0),
            ObsTerm(name="target_pos_left", size=3, scale=1.0, clip=100.0),
            ObsTerm(name="target_pos_right", size=3, scale=1.0, clip=100.0),
        ),
    )
