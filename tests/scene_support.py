"""A test scene: the robot plus a spring-loaded key in front of it and a pendulum hung from the left hand.

The key is what a piano task attaches (a body on a hinge with a spring, a collider in its own collision
group that touches both arms, a site and a joint-position sensor). The pendulum's hinge hangs below the
left hand, so in the compiled tree (depth first) its coordinate sits between the left arm's 7 and the right
arm's 7: the robot's joints are then not the first n coordinates, which is what addressing by name is for.
"""

from __future__ import annotations

import mujoco

from bar_policy.robot.links import COLLISION_BITS

KEY_JOINT = "test_key_hinge"
KEY_SENSOR = "test_key_angle"
KEY_SITE = "test_key_top"
PENDULUM_JOINT = "test_pendulum_hinge"
EXTRA_JOINTS = (PENDULUM_JOINT, KEY_JOINT)
"""The scene's joints besides the robot's."""

KEY_POS = (0.45, 0.0, 0.1)
"""Key hinge in the world (chest) frame, m: in front of the chest, clear of both arms at piano_ready."""
KEY_MASS = 0.03  # kg
KEY_HALF = (0.07, 0.011, 0.01)  # box half extents, m; the box reaches from the hinge to 0.14 m in -x
KEY_STIFFNESS = 2.0  # N*m/rad
KEY_DAMPING = 0.05  # N*m*s/rad
KEY_RANGE = (-0.1, 0.0)  # rad: pressing the free end down is a negative rotation about +y

# The key collides with both arms and nothing else: its conaffinity holds the arms' contype bits (2 | 4), its
# contype is 0, so it touches neither the torso (contype 1) nor another key.
KEY_CONTYPE = 0
KEY_CONAFFINITY = COLLISION_BITS["left"][0] | COLLISION_BITS["right"][0]


def key_scene(spec: mujoco.MjSpec, key_pos: tuple[float, float, float] = KEY_POS) -> None:
    """Add the key (at ``key_pos``, m) and the hand pendulum to the robot's spec (a ``SceneEdit``)."""
    key = spec.worldbody.add_body(name="test_key", pos=key_pos)
    key.add_joint(
        name=KEY_JOINT,
        type=mujoco.mjtJoint.mjJNT_HINGE,
        axis=[0, 1, 0],
        range=KEY_RANGE,
        stiffness=KEY_STIFFNESS,
        damping=KEY_DAMPING,
    )
    key.add_geom(
        name="test_key_geom",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=KEY_HALF,
        pos=[-KEY_HALF[0], 0, 0],
        mass=KEY_MASS,
        contype=KEY_CONTYPE,
        conaffinity=KEY_CONAFFINITY,
    )
    key.add_site(name=KEY_SITE, pos=[-2 * KEY_HALF[0], 0, KEY_HALF[2]])
    spec.add_sensor(
        name=KEY_SENSOR,
        type=mujoco.mjtSensor.mjSENS_JOINTPOS,
        objtype=mujoco.mjtObj.mjOBJ_JOINT,
        objname=KEY_JOINT,
    )
    pendulum = spec.body("left_hand").add_body(name="test_pendulum", pos=[0.0, 0.1, -0.04])
    pendulum.add_joint(name=PENDULUM_JOINT, type=mujoco.mjtJoint.mjJNT_HINGE, axis=[1, 0, 0], damping=0.01)
    pendulum.add_geom(
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.01, 0, 0],
        pos=[0, 0, -0.03],
        mass=0.01,
        contype=0,
        conaffinity=0,
    )
