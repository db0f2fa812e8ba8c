"""The piano observation layout (``lite_piano_<mode>``), frozen by its golden file in ``obs/schemas/``.

Humanoid Control's piano terms first, in its order (``target_keys, progress, key_pressed``), then the joint
state and the last action (lite-model.md).
"""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema, ObsTerm
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the piano layout: goal keys (11 frames x 49 keys), progress, keys down, q, dq, action."""
    robot = load_robot(mode)
    n = robot.num_joints
    return ObservationSchema(
        name=f"lite_piano_{mode}",
        version=1,
        robot=robot.robot,
        mode=mode,
        joint_names=robot.joint_names,
        action_joint_names=robot.joint_names,
        default_joint_pos=tuple(float(x) for x in robot.pose("piano_ready")),
        terms=(
            ObsTerm(name="target_keys", size=TARGET_FRAMES * PIANO_KEYS, scale=1.0, clip=100.0),
            ObsTerm(name="progress", size=1, scale=1.0, clip=100.0),
            ObsTerm(name="key_pressed", size=PIANO_KEYS, scale=1.0, clip=100.0),
            ObsTerm(name="joint_pos", size=n, scale=1.0, clip=100.0),
            ObsTerm(name="joint_vel", size=n, scale=0.1, clip=100.0),
            ObsTerm(name="actions", size=n, scale=1.0, clip=100.0),
        ),
    )
