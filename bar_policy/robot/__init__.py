"""What the robot is: joint table, Robstride models, the model's joint addresses and the MIT law (no jax).

The MuJoCo model itself (``bar_policy.robot.scene``, an ``MjSpec`` a task extends) imports mujoco and is
not re-exported here.
"""

from bar_policy.robot.actuators import ROBSTRIDE_MODELS, RobstrideSpec, robstride_spec
from bar_policy.robot.constants import (
    FINGERTIP_SITES,
    MODES,
    POSE_NAMES,
    JointSpec,
    RobotSpec,
    load_robot,
)
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand, mit_torque, quantize_command

__all__ = [
    "FINGERTIP_SITES",
    "MODES",
    "POSE_NAMES",
    "ROBSTRIDE_MODELS",
    "JointSpec",
    "MitCommand",
    "RobotIndex",
    "RobotSpec",
    "RobstrideSpec",
    "load_robot",
    "mit_torque",
    "quantize_command",
    "robstride_spec",
]
