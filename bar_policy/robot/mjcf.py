"""MJCF of the Lite upper body (``lite_dummy``), generated from the numbers of lite-model.md section 4.

Two modes share one kinematic description:

- ``arms`` (14 joints): the neck links and head are one rigid body fixed to the chest (the real robot today:
  the neck motors are not on the bus).
- ``arms_neck`` (17 joints): neck_yaw -> neck_roll -> head (joint ``neck_pitch``).

Every body has the world orientation at q = 0, each joint sits at its body origin (lite-model.md 4.1; this
re-expression matched the CAD model to 6 um in forward kinematics). Collision shapes are the upstream
primitive colliders (4.4). Joint limits, armature, frictionloss and actuator ranges are written from the
joint table (``lite_dummy.json``), so there is one source of truth; ``tests/test_mjcf.py`` checks the
compiled model against it.

Physics options (see ``docs/physics.md``): timestep 2 ms, Euler. The MIT law is applied through
``qfrc_applied`` each physics step (as mujoco_ros2_control's MujocoSystem does). Its damping term is stiff:
the smallest joint-space inertia is 0.00212 kg*m^2 (a wrist rotor), so a purely explicit update at 2 ms is
stable for Kd = 2 N*m*s/rad by only ~3%. The env and the sim target therefore integrate the Kd term
implicitly through Euler's joint damping while applying exactly the firmware torque (docs/physics.md 3).

Contacts are frictionless (condim 1): they only keep links apart (self-collision), and one constraint row
per contact instead of four keeps MJX's solver small (nefc 82 instead of 244 per env). The Newton solver
is capped at 3 iterations (5 line-search steps): with frictionless contacts, joint limits and frictionloss it
converges in 1-2 iterations, and the cap bounds MJX's batched while-loop (H100, batch 8192: 0.73M physics
steps/s with condim 3 and 6 iterations, 1.26M with condim 1, 1.72M with condim 1 and 3 iterations;
``bench/mjx_variants.py``, docs/benchmarks.md).

Collision filtering: torso (chest, head) collides with both arms, and the arms collide with each other;
links of one arm do not collide with each other (the joint limits keep them apart), and the chest does not
collide with the shoulder_yaw capsules, which sit 14 mm inside it when the arms hang (lite-model.md 4.4).
"""

from __future__ import annotations

from functools import cache

from bar_policy.robot.constants import MODES, POSE_NAMES, RobotSpec, load_robot

__all__ = ["PHYSICS_DT", "lite_xml", "load_model"]

PHYSICS_DT = 0.002
"""Physics timestep, s (500 Hz)."""

# (body, parent, pos, joint axis, mass, com, inertia(xx, yy, zz, xy, xz, yz)) for the LEFT arm, world
# frame at q = 0. The right arm is the mirror in y (axes per lite-model.md 4.1, checked by the tests).
_LEFT_ARM = (
    ("left_shoulder_pitch", "chest", (0, 0.09, 0.39), (0, 0.98481, 0.17365), 0.375,
     (0, -0.00701, 0.00048), (0.0002327, 0.000196, 0.000237, 0, 0, 7.525e-06)),
    ("left_shoulder_roll", "left_shoulder_pitch", (0, 0, 0), (1, 0, 0), 0.42,
     (0, 0.0789, 0), (0.0005054, 0.0002055, 0.0005355, 0, 0, 0)),
    ("left_shoulder_yaw", "left_shoulder_roll", (0, 0.12, 0), (0, -1, 0), 0.43,
     (0.00516, 0.05544, 0), (0.0004967, 0.0002214, 0.0005011, -4.803e-05, 0, 0)),
    ("left_elbow_pitch", "left_shoulder_yaw", (0.01, 0.08, 0), (0, 0, 1), 0.11,
     (-0.00846, 0.02604, 0), (0.0001179, 9.394e-05, 8.093e-05, 8.133e-06, 0, 0)),
    ("left_wrist_yaw", "left_elbow_pitch", (-0.01, 0.055, 0), (0, -1, 0), 0.54,
     (0, 0.0578, 0.00014), (0.0008261, 0.0002682, 0.0008175, 0, 0, 8.159e-06)),
    ("left_wrist_roll", "left_wrist_yaw", (0, 0.135, 0), (0, 0, 1), 0.25,
     (0, 0, 0), (7.927e-05, 9.191e-05, 9.041e-05, 0, 0, 0)),
    ("left_hand", "left_wrist_roll", (0, 0, 0), (1, 0, 0), 0.167493,
     (0.00606, 0.1008, -0.00441), (0.0004076, 9.831e-05, 0.0004563, -4.353e-05, 0, 0)),
)  # fmt: skip
_RIGHT_ARM = (
    ("right_shoulder_pitch", "chest", (0, -0.09, 0.39), (0, 0.98481, -0.17365), 0.375,
     (0, 0.00701, 0.00048), (0.0002327, 0.000196, 0.000237, 0, 0, -7.525e-06)),
    ("right_shoulder_roll", "right_shoulder_pitch", (0, 0, 0), (1, 0, 0), 0.42073,
     (0, -0.07897, 0.00004), (0.0005071, 0.0002059, 0.0005369, 0, 0, 0)),
    ("right_shoulder_yaw", "right_shoulder_roll", (0, -0.12, 0), (0, 1, 0), 0.43,
     (0.00516, -0.05544, 0), (0.0004967, 0.0002214, 0.0005011, 4.803e-05, 0, 0)),
    ("right_elbow_pitch", "right_shoulder_yaw", (0.01, -0.08, 0), (0, 0, -1), 0.11,
     (-0.00846, -0.02604, 0), (0.0001179, 9.394e-05, 8.093e-05, -8.137e-06, 0, 0)),
    ("right_wrist_yaw", "right_elbow_pitch", (-0.01, -0.055, 0), (0, 1, 0), 0.54,
     (0, -0.0578, -0.00014), (0.0008261, 0.0002682, 0.0008175, 0, 0, 8.157e-06)),
    ("right_wrist_roll", "right_wrist_yaw", (0, -0.135, 0), (0, 0, -1), 0.25,
     (0, 0, 0), (7.927e-05, 9.191e-05, 9.041e-05, 0, 0, 0)),
    ("right_hand", "right_wrist_roll", (0, 0, 0), (1, 0, 0), 0.167493,
     (0.00606, -0.1008, -0.00441), (0.0004076, 9.831e-05, 0.0004563, 4.353e-05, 0, 0)),
)  # fmt: skip
_NECK = (
    ("neck_yaw", "chest", (-0.01, 0, 0.45), (0, 0, 1), 0.0779115,
     (0, 0, 0.03), (1.558e-05, 2.402e-05, 2.402e-05, 0, 0, 0)),
    ("neck_roll", "neck_yaw", (0, 0, 0.03), (1, 0, 0), 0.0779115,
     (0, 0, 0.03), (2.402e-05, 1.558e-05, 2.402e-05, 0, 0, 0)),
    ("head", "neck_roll", (0, 0, 0.03), (0, 1, 0), 4.7098,
     (-0.00135, 0, 0.05848), (0.01928, 0.02011, 0.01579, 0, 0.001808, 0)),
)  # fmt: skip
_JOINT_OF_BODY = {"left_hand": "left_wrist_pitch", "right_hand": "right_wrist_pitch", "head": "neck_pitch"}

# Colliders in body frames (lite-model.md 4.4); the right arm mirrors y. (body, xml attributes)
_LEFT_GEOMS = (
    ("left_shoulder_yaw", 'type="capsule" size="0.035" fromto="0 -0.12 0 0 0 0"'),
    ("left_wrist_yaw", 'type="capsule" size="0.03" fromto="0 0.135 0 0 -0.055 0"'),
    ("left_hand", 'type="capsule" size="0.035" fromto="0.0005 0.08 -0.01 0.0005 0.12 -0.01"'),
    ("left_hand", 'type="capsule" size="0.006" fromto="0.0225 0.164 0.007 0.0225 0.224 0.007"'),
)
_RIGHT_GEOMS = (
    ("right_shoulder_yaw", 'type="capsule" size="0.035" fromto="0 0.12 0 0 0 0"'),
    ("right_wrist_yaw", 'type="capsule" size="0.03" fromto="0 -0.135 0 0 0.055 0"'),
    ("right_hand", 'type="capsule" size="0.035" fromto="0.0005 -0.08 -0.01 0.0005 -0.12 -0.01"'),
    ("right_hand", 'type="capsule" size="0.006" fromto="0.0225 -0.164 0.007 0.0225 -0.224 0.007"'),
)
# contype / conaffinity bits: 1 torso, 2 left arm, 4 right arm (see the module docstring).
_COLLIDE = {"torso": (1, 6), "left": (2, 5), "right": (4, 3)}
_ARM_RGBA = "0.65 0.68 0.72 1"


def _fmt(values: tuple[float, ...]) -> str:
    return " ".join(repr(float(v)) for v in values)


def _body_xml(
    body: tuple, robot: RobotSpec | None, geoms: list[str], side: str, sites: str = ""
) -> tuple[str, str]:
    """Open-tag + content for one body (joint, inertial, geoms); returns (open_part, name)."""
    name, _parent, pos, axis, mass, com, inertia = body
    joint_name = _JOINT_OF_BODY.get(name, name)
    lines = [f'<body name="{name}" pos="{_fmt(pos)}">']
    lines.append(f'  <inertial pos="{_fmt(com)}" mass="{mass:.9g}" fullinertia="{_fmt(inertia)}"/>')
    if robot is not None:
        j = robot.joints[robot.index(joint_name)]
        lines.append(
            f'  <joint name="{joint_name}" axis="{_fmt(axis)}" range="{j.lower!r} {j.upper!r}" '
            f'armature="{j.armature!r}" frictionloss="{j.frictionloss!r}" '
            f'actuatorfrcrange="{-j.sim_effort!r} {j.sim_effort!r}"/>'
        )
    contype, conaff = _COLLIDE[side]
    for g in geoms:
        lines.append(f'  <geom {g} contype="{contype}" conaffinity="{conaff}" rgba="{_ARM_RGBA}"/>')
    if sites:
        lines.append(sites)
    return "\n".join(lines), name


def _chain_xml(chain: tuple, robot: RobotSpec | None, geom_table: tuple, side: str, tip: str) -> str:
    """Nested body XML of a serial chain (each body is the previous one's child)."""
    opens = []
    for k, body in enumerate(chain):
        geoms = [attrs for b, attrs in geom_table if b == body[0]]
        sites = tip if k == len(chain) - 1 else ""
        text, _ = _body_xml(body, robot, geoms, side, sites)
        opens.append(text)
    out = ""
    for text in reversed(opens):
        inner = "\n".join("  " + line for line in out.splitlines())
        out = text + ("\n" + inner if inner else "") + "\n</body>"
    return out


def lite_xml(mode: str = "arms") -> str:
    """The MJCF text of the Lite upper body for ``mode`` (``arms`` or ``arms_neck``)."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid modes: {list(MODES)}")
    robot = load_robot(mode)
    tip_l = '  <site name="left_finger2_tip" pos="0.0225 0.225 0.007" size="0.008" rgba="1 0.3 0.3 1"/>'
    tip_r = '  <site name="right_finger2_tip" pos="0.0225 -0.225 0.007" size="0.008" rgba="1 0.3 0.3 1"/>'
    left = _chain_xml(_LEFT_ARM, robot, _LEFT_GEOMS, "left", tip_l)
    right = _chain_xml(_RIGHT_ARM, robot, _RIGHT_GEOMS, "right", tip_r)
    t_ct, t_ca = _COLLIDE["torso"]
    head_geom = f'contype="{t_ct}" conaffinity="{t_ca}" rgba="0.3 0.3 0.35 1"'
    if mode == "arms_neck":
        head = _chain_xml(_NECK, robot, (), "torso", "")
        head = head.replace(
            '<body name="head" pos="0 0 0.03">',
            '<body name="head" pos="0 0 0.03">\n  <geom type="capsule" size="0.09" '
            f'fromto="0 0 0.035 0 0 0.065" {head_geom}/>',
        )
    else:
        # Neck links and head lumped into one rigid body (lite-model.md 4.5).
        head = (
            '<body name="head" pos="0 0 0">\n'
            '  <inertial pos="-0.01131 0 0.56613" mass="4.8656" '
            'fullinertia="0.02017 0.021 0.01584 0 0.001823 0"/>\n'
            f'  <geom type="capsule" size="0.09" fromto="-0.01 0 0.545 -0.01 0 0.575" {head_geom}/>\n'
            "</body>"
        )
    actuators = "\n".join(
        f'    <motor name="{j.name}" joint="{j.name}" ctrlrange="{-j.sim_effort!r} {j.sim_effort!r}" '
        f'forcerange="{-j.sim_effort!r} {j.sim_effort!r}"/>'
        for j in robot.joints
    )
    keys = "\n".join(f'    <key name="{p}" qpos="{_fmt(tuple(robot.pose(p)))}"/>' for p in POSE_NAMES)
    chest_geoms = (
        f'  <geom type="capsule" size="0.053" fromto="0.043 0 0.202 0.007 0 0.358" {head_geom}/>\n'
        f'  <geom type="box" size="0.02 0.04 0.09" pos="0.015 -0.04 0.32" '
        f'quat="0.7069 0.0185 -0.1410 -0.6929" {head_geom}/>\n'
        f'  <geom type="box" size="0.02 0.04 0.09" pos="0.015 0.04 0.32" '
        f'quat="0.6929 0.1410 -0.0185 -0.7069" {head_geom}/>'
    )

    def indent(text: str, n: int) -> str:
        return "\n".join(" " * n + line for line in text.splitlines())

    return f"""<mujoco model="lite_dummy_{mode}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_DT}" integrator="Euler" iterations="3" ls_iterations="5"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <default><geom condim="1"/></default>
  <worldbody>
    <light pos="0.6 0 1.5" dir="-0.4 0 -1"/>
    <geom name="floor" type="plane" size="1 1 0.05" rgba="0.85 0.85 0.85 1" contype="0" conaffinity="0"/>
    <camera name="front" pos="1.3 0 0.55" xyaxes="0 1 0 -0.25 0 1"/>
    <body name="chest" pos="0 0 0">
      <inertial pos="0.02298 0 0.30125" mass="4.241" fullinertia="0.0294 0.02931 0.01032 0 0.003714 0"/>
{indent(chest_geoms, 4)}
{indent(left, 6)}
{indent(right, 6)}
{indent(head, 6)}
    </body>
  </worldbody>
  <contact>
    <exclude body1="chest" body2="left_shoulder_yaw"/>
    <exclude body1="chest" body2="right_shoulder_yaw"/>
  </contact>
  <actuator>
{actuators}
  </actuator>
  <keyframe>
{keys}
  </keyframe>
</mujoco>
"""


@cache
def _compiled(mode: str):  # noqa: ANN202 - mujoco.MjModel, imported lazily
    import mujoco

    return mujoco.MjModel.from_xml_string(lite_xml(mode))


def load_model(mode: str = "arms"):  # noqa: ANN201 - mujoco.MjModel
    """Compile the Lite MJCF for ``mode`` with C MuJoCo. Returns a fresh copy (callers may mutate it)."""
    import copy

    return copy.deepcopy(_compiled(mode))
