"""The Lite's links as data: bodies, inertias, joint axes, colliders and collision bits (lite-model.md 4).

Numbers only; ``bar_policy.robot.scene`` builds the ``mujoco.MjSpec`` from them. Every body has the world
orientation at q = 0 and each joint sits at its body origin (lite-model.md 4.1; this re-expression matched
the CAD model to 6 um in forward kinematics). Positions are m, masses kg, inertias kg*m^2 about the
centre of mass, in the body frame. The right arm is the mirror of the left in y (axes per lite-model.md
4.1, checked by tests/test_mjcf.py). Collision shapes are the upstream primitive colliders (4.4).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "ARM_RGBA",
    "CHEST",
    "CHEST_BOXES",
    "CHEST_CAPSULE",
    "COLLISION_BITS",
    "FINGERTIP_SITE_POS",
    "HEAD_CAPSULE",
    "HEAD_LUMPED",
    "HEAD_LUMPED_CAPSULE",
    "JOINT_OF_BODY",
    "LEFT_ARM",
    "LEFT_COLLIDERS",
    "NECK",
    "RIGHT_ARM",
    "RIGHT_COLLIDERS",
    "TORSO_RGBA",
    "Box",
    "Capsule",
    "Inertial",
    "Link",
]

Vec3 = tuple[float, float, float]


class Inertial(NamedTuple):
    """Mass properties of one body."""

    com: Vec3
    """Centre of mass in the body frame, m."""
    mass: float
    """kg."""
    inertia: tuple[float, float, float, float, float, float]
    """Full inertia (xx, yy, zz, xy, xz, yz) about the centre of mass, body-frame axes, kg*m^2."""


class Link(NamedTuple):
    """One jointed body of a serial chain: its pose in the parent at q = 0, joint axis and mass."""

    name: str
    """Body name (its joint's name unless ``JOINT_OF_BODY`` says otherwise)."""
    parent: str
    """Parent body name."""
    pos: Vec3
    """Body origin (= joint position) in the parent frame, m."""
    axis: Vec3
    """Hinge axis in the body frame (= world frame at q = 0)."""
    inertial: Inertial
    """Mass properties."""


class Capsule(NamedTuple):
    """A capsule collider between two points of its body's frame."""

    body: str
    """Body name."""
    radius: float
    """m."""
    fromto: tuple[float, float, float, float, float, float]
    """End points (x1, y1, z1, x2, y2, z2) in the body frame, m."""


class Box(NamedTuple):
    """A box collider of the chest."""

    half_size: Vec3
    """Half extents, m."""
    pos: Vec3
    """Centre in the body frame, m."""
    quat: tuple[float, float, float, float]
    """Orientation in the body frame (w, x, y, z), as written in lite-model.md 4.4 (MuJoCo normalises)."""


def _link(name: str, parent: str, pos: Vec3, axis: Vec3, mass: float, com: Vec3, inertia: tuple) -> Link:
    return Link(name, parent, pos, axis, Inertial(com, mass, inertia))


# -- bodies ------------------------------------------------------------------------------------------
CHEST = Inertial((0.02298, 0, 0.30125), 4.241, (0.0294, 0.02931, 0.01032, 0, 0.003714, 0))
"""The chest: the fixed root at the world origin."""

LEFT_ARM: tuple[Link, ...] = (
    _link(
        "left_shoulder_pitch",
        "chest",
        (0, 0.09, 0.39),
        (0, 0.98481, 0.17365),
        0.375,
        (0, -0.00701, 0.00048),
        (0.0002327, 0.000196, 0.000237, 0, 0, 7.525e-06),
    ),
    _link(
        "left_shoulder_roll",
        "left_shoulder_pitch",
        (0, 0, 0),
        (1, 0, 0),
        0.42,
        (0, 0.0789, 0),
        (0.0005054, 0.0002055, 0.0005355, 0, 0, 0),
    ),
    _link(
        "left_shoulder_yaw",
        "left_shoulder_roll",
        (0, 0.12, 0),
        (0, -1, 0),
        0.43,
        (0.00516, 0.05544, 0),
        (0.0004967, 0.0002214, 0.0005011, -4.803e-05, 0, 0),
    ),
    _link(
        "left_elbow_pitch",
        "left_shoulder_yaw",
        (0.01, 0.08, 0),
        (0, 0, 1),
        0.11,
        (-0.00846, 0.02604, 0),
        (0.0001179, 9.394e-05, 8.093e-05, 8.133e-06, 0, 0),
    ),
    _link(
        "left_wrist_yaw",
        "left_elbow_pitch",
        (-0.01, 0.055, 0),
        (0, -1, 0),
        0.54,
        (0, 0.0578, 0.00014),
        (0.0008261, 0.0002682, 0.0008175, 0, 0, 8.159e-06),
    ),
    _link(
        "left_wrist_roll",
        "left_wrist_yaw",
        (0, 0.135, 0),
        (0, 0, 1),
        0.25,
        (0, 0, 0),
        (7.927e-05, 9.191e-05, 9.041e-05, 0, 0, 0),
    ),
    _link(
        "left_hand",
        "left_wrist_roll",
        (0, 0, 0),
        (1, 0, 0),
        0.167493,
        (0.00606, 0.1008, -0.00441),
        (0.0004076, 9.831e-05, 0.0004563, -4.353e-05, 0, 0),
    ),
)
"""The left arm, shoulder to hand."""

RIGHT_ARM: tuple[Link, ...] = (
    _link(
        "right_shoulder_pitch",
        "chest",
        (0, -0.09, 0.39),
        (0, 0.98481, -0.17365),
        0.375,
        (0, 0.00701, 0.00048),
        (0.0002327, 0.000196, 0.000237, 0, 0, -7.525e-06),
    ),
    _link(
        "right_shoulder_roll",
        "right_shoulder_pitch",
        (0, 0, 0),
        (1, 0, 0),
        0.42073,
        (0, -0.07897, 0.00004),
        (0.0005071, 0.0002059, 0.0005369, 0, 0, 0),
    ),
    _link(
        "right_shoulder_yaw",
        "right_shoulder_roll",
        (0, -0.12, 0),
        (0, 1, 0),
        0.43,
        (0.00516, -0.05544, 0),
        (0.0004967, 0.0002214, 0.0005011, 4.803e-05, 0, 0),
    ),
    _link(
        "right_elbow_pitch",
        "right_shoulder_yaw",
        (0.01, -0.08, 0),
        (0, 0, -1),
        0.11,
        (-0.00846, -0.02604, 0),
        (0.0001179, 9.394e-05, 8.093e-05, -8.137e-06, 0, 0),
    ),
    _link(
        "right_wrist_yaw",
        "right_elbow_pitch",
        (-0.01, -0.055, 0),
        (0, 1, 0),
        0.54,
        (0, -0.0578, -0.00014),
        (0.0008261, 0.0002682, 0.0008175, 0, 0, 8.157e-06),
    ),
    _link(
        "right_wrist_roll",
        "right_wrist_yaw",
        (0, -0.135, 0),
        (0, 0, -1),
        0.25,
        (0, 0, 0),
        (7.927e-05, 9.191e-05, 9.041e-05, 0, 0, 0),
    ),
    _link(
        "right_hand",
        "right_wrist_roll",
        (0, 0, 0),
        (1, 0, 0),
        0.167493,
        (0.00606, -0.1008, -0.00441),
        (0.0004076, 9.831e-05, 0.0004563, 4.353e-05, 0, 0),
    ),
)
"""The right arm, shoulder to hand."""

NECK: tuple[Link, ...] = (
    _link(
        "neck_yaw",
        "chest",
        (-0.01, 0, 0.45),
        (0, 0, 1),
        0.0779115,
        (0, 0, 0.03),
        (1.558e-05, 2.402e-05, 2.402e-05, 0, 0, 0),
    ),
    _link(
        "neck_roll",
        "neck_yaw",
        (0, 0, 0.03),
        (1, 0, 0),
        0.0779115,
        (0, 0, 0.03),
        (2.402e-05, 1.558e-05, 2.402e-05, 0, 0, 0),
    ),
    _link(
        "head",
        "neck_roll",
        (0, 0, 0.03),
        (0, 1, 0),
        4.7098,
        (-0.00135, 0, 0.05848),
        (0.01928, 0.02011, 0.01579, 0, 0.001808, 0),
    ),
)
"""The neck of ``arms_neck``: neck_yaw -> neck_roll -> head (joint ``neck_pitch``)."""

HEAD_LUMPED = Inertial((-0.01131, 0, 0.56613), 4.8656, (0.02017, 0.021, 0.01584, 0, 0.001823, 0))
"""``arms``: neck links and head as one rigid body fixed to the chest at its origin (lite-model.md 4.5)."""

JOINT_OF_BODY: dict[str, str] = {
    "left_hand": "left_wrist_pitch",
    "right_hand": "right_wrist_pitch",
    "head": "neck_pitch",
}
"""Bodies whose joint is not named after the body."""

FINGERTIP_SITE_POS: dict[str, Vec3] = {
    "left_finger2_tip": (0.0225, 0.225, 0.007),
    "right_finger2_tip": (0.0225, -0.225, 0.007),
}
"""Fingertip sites in the hand frames, m (``constants.FINGERTIP_SITES``; on the last arm body)."""

# -- colliders ---------------------------------------------------------------------------------------
LEFT_COLLIDERS: tuple[Capsule, ...] = (
    Capsule("left_shoulder_yaw", 0.035, (0, -0.12, 0, 0, 0, 0)),
    Capsule("left_wrist_yaw", 0.03, (0, 0.135, 0, 0, -0.055, 0)),
    Capsule("left_hand", 0.035, (0.0005, 0.08, -0.01, 0.0005, 0.12, -0.01)),
    Capsule("left_hand", 0.006, (0.0225, 0.164, 0.007, 0.0225, 0.224, 0.007)),
)
"""Colliders of the left arm (the last one is the finger, ending 1 mm short of the fingertip site)."""
RIGHT_COLLIDERS: tuple[Capsule, ...] = (
    Capsule("right_shoulder_yaw", 0.035, (0, 0.12, 0, 0, 0, 0)),
    Capsule("right_wrist_yaw", 0.03, (0, -0.135, 0, 0, 0.055, 0)),
    Capsule("right_hand", 0.035, (0.0005, -0.08, -0.01, 0.0005, -0.12, -0.01)),
    Capsule("right_hand", 0.006, (0.0225, -0.164, 0.007, 0.0225, -0.224, 0.007)),
)
"""Colliders of the right arm (mirror of the left)."""
CHEST_CAPSULE = Capsule("chest", 0.053, (0.043, 0, 0.202, 0.007, 0, 0.358))
"""The chest's spine capsule."""
CHEST_BOXES: tuple[Box, ...] = (
    Box((0.02, 0.04, 0.09), (0.015, -0.04, 0.32), (0.7069, 0.0185, -0.1410, -0.6929)),
    Box((0.02, 0.04, 0.09), (0.015, 0.04, 0.32), (0.6929, 0.1410, -0.0185, -0.7069)),
)
"""The chest's two shoulder-blade boxes."""
HEAD_CAPSULE = Capsule("head", 0.09, (0, 0, 0.035, 0, 0, 0.065))
"""The head collider meant for ``arms_neck`` (head frame). Not in the model: the first (text-template) MJCF
never added it, and the scene keeps that model unchanged (tests/robot/test_scene.py); adding it is a
deliberate change of ``arms_neck`` (head-arm contacts)."""
HEAD_LUMPED_CAPSULE = Capsule("head", 0.09, (-0.01, 0, 0.545, -0.01, 0, 0.575))
"""The head collider of ``arms`` (the lumped head's frame is the chest's)."""

COLLISION_BITS: dict[str, tuple[int, int]] = {"torso": (1, 6), "left": (2, 5), "right": (4, 3)}
"""``(contype, conaffinity)`` per group: bit 1 torso (chest, head), 2 left arm, 4 right arm.

The torso collides with both arms and the arms with each other; links of one arm do not collide with each
other (the joint limits keep them apart). Two geoms collide when ``contype1 & conaffinity2`` or
``contype2 & conaffinity1`` is non-zero, so a scene object with ``contype = 0, conaffinity = 2 | 4``
touches both arms (not the torso, not other such objects) without changing the robot's bits.
"""

ARM_RGBA = (0.65, 0.68, 0.72, 1.0)
"""Colour of the arm colliders."""
TORSO_RGBA = (0.3, 0.3, 0.35, 1.0)
"""Colour of the chest and head colliders."""
