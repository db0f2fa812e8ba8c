"""What the robot is: joint table, Robstride models, MJCF and the MIT law (numpy only, no jax)."""

from bar_policy.robot.actuators import ROBSTRIDE_MODELS, RobstrideSpec, robstride_spec
from bar_policy.robot.constants import (
    FINGERTIP_SITES,
    MODES,
    POSE_NAMES,
    JointSpec,
    RobotSpec,
    load_robot,
)
from bar_policy.robot.mit import MitCommand, mit_torque, quantize_command

__all__ = [
    "FINGERTIP_SITES",
    "MODES",
    "POSE_NAMES",
    "ROBSTRIDE_MODELS",
    "JointSpec",
    "MitCommand",
    "RobotSpec",
    "RobstrideSpec",
    "load_robot",
    "mit_torque",
    "quantize_command",
    "robstride_spec",
]
