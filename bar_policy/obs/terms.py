"""The catalogue of observation terms: every name an observation schema may use, with its size rule.

A term reads one named input array and contributes ``clip((input - offset) * scale)`` to the observation.
Sizes are fixed by the term (3 for a position) or by the joint set (``"joints"``: one per joint,
``"actions"``: one per action joint), or, for the reference terms of the tracking task, by the schema's
``lookahead_steps`` K and ``body_names`` (B bodies): ``"lookahead_joints"`` = K * joints,
``"lookahead_body_pos"`` = K * B * 3, ``"lookahead_body_ori"`` = K * B * 6. Adding a term here is an API
change: schemas that use it get a new version, existing golden schemas stay valid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["LOOKAHEAD_RULES", "TERM_CATALOG", "TermKind"]

SizeRule = int | Literal["joints", "actions", "lookahead_joints", "lookahead_body_pos", "lookahead_body_ori"]

LOOKAHEAD_RULES = ("lookahead_joints", "lookahead_body_pos", "lookahead_body_ori")
"""Size rules that need the schema's ``lookahead_steps`` (and ``body_names`` for the body terms)."""


@dataclass(frozen=True, kw_only=True)
class TermKind:
    """What a term name means."""

    size: SizeRule
    """Fixed size, ``"joints"`` / ``"actions"`` for one entry per (action) joint, or a lookahead rule."""
    category: Literal["state", "command", "action", "imu"]
    """Where the input comes from at deploy time: robot state, the command source, the policy, the IMU."""
    offset_default_pose: bool = False
    """True when the default joint pose is subtracted before scaling (``joint_pos``)."""
    unit: str = ""
    """Unit of the raw input."""
    doc: str = ""


TERM_CATALOG: dict[str, TermKind] = {
    "joint_pos": TermKind(
        size="joints", category="state", offset_default_pose=True, unit="rad",
        doc="q - default_joint_pos, canonical joint order",
    ),
    "joint_vel": TermKind(size="joints", category="state", unit="rad/s", doc="dq, canonical order"),
    "actions": TermKind(size="actions", category="action", doc="previous policy output (raw action)"),
    "fingertip_pos_left": TermKind(
        size=3, category="state", unit="m", doc="left finger2_tip site, chest frame (forward kinematics)"
    ),
    "fingertip_pos_right": TermKind(
        size=3, category="state", unit="m", doc="right finger2_tip site in the chest frame"
    ),
    "target_pos_left": TermKind(
        size=3, category="command", unit="m", doc="left fingertip target in the chest frame"
    ),
    "target_pos_right": TermKind(
        size=3, category="command", unit="m", doc="right fingertip target in the chest frame"
    ),
    "motion_joint_pos": TermKind(
        size="lookahead_joints", category="command", unit="rad",
        doc="reference joint positions at the next lookahead_steps frames, frame-major, canonical order",
    ),
    "motion_body_pos_b": TermKind(
        size="lookahead_body_pos", category="command", unit="m",
        doc="reference positions of body_names in the chest (torso) frame at the next lookahead_steps "
        "frames; frame-major, then body, then xyz (Humanoid Control's name)",
    ),
    "motion_body_ori_b": TermKind(
        size="lookahead_body_ori", category="command", unit="1",
        doc="reference orientations of body_names in the chest frame as 6-D (rotation matrix columns 0-1, "
        "row-major) at the next lookahead_steps frames; frame-major, then body (Humanoid Control's name)",
    ),
    "projected_gravity": TermKind(size=3, category="imu", unit="1", doc="gravity direction, IMU frame"),
    "imu_quaternion": TermKind(size=4, category="imu", unit="1", doc="orientation (w, x, y, z)"),
    "imu_angular_velocity": TermKind(size=3, category="imu", unit="rad/s", doc="gyroscope"),
    "imu_linear_acceleration": TermKind(size=3, category="imu", unit="m/s^2", doc="accelerometer"),
}  # fmt: skip
