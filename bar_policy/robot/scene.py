"""The Lite's scene as a ``mujoco.MjSpec``: the robot built in code, which a task extends before compiling.

``robot_spec(mode)`` returns a fresh spec of the robot alone (the links of ``links.py``, the joint
properties of the joint table ``lite_dummy.json``); a task adds its own bodies, joints, geoms, sites,
sensors, actuators or contact pairs to it (``spec.worldbody.add_body(...)``, ``spec.add_sensor(...)``,
``spec.attach(...)``) and ``compile_scene`` compiles it. The usual entry is ``load_model(mode, scene)``
where ``scene`` is a ``SceneEdit``, a function that edits the spec in place: the env, the sim target, the
emulator and ``Kinematics`` all take the same ``scene`` argument, so a task's additions exist on every
side. The robot's joints are found in a compiled scene by name (``bar_policy.robot.index.RobotIndex``),
never by position, so extra joints anywhere in the tree are fine. See docs/scenes.md.

Two modes share one kinematic description:

- ``arms`` (14 joints): the neck links and head are one rigid body fixed to the chest (the real robot today:
  the neck motors are not on the bus).
- ``arms_neck`` (17 joints): neck_yaw -> neck_roll -> head (joint ``neck_pitch``).

Physics options (see ``docs/physics.md``): timestep 2 ms, Euler. The MIT law is applied through
``qfrc_applied`` each physics step (as mujoco_ros2_control's MujocoSystem does); the MJCF's actuators
(``motor``, one per joint, named after it) only carry the torque ranges. The law's damping term is stiff
(the smallest joint-space inertia is 0.00212 kg*m^2, a wrist rotor: explicit Euler at 2 ms is stable for
Kd = 2 N*m*s/rad by only ~3%), so the env and the sim target integrate it implicitly through Euler's joint
damping while applying exactly the firmware torque (docs/physics.md 3).

Contacts are frictionless (``condim`` 1, the main default class, so a task's geoms get it too unless they
set their own): they only keep links apart, and one constraint row per contact instead of four keeps
MJX's solver small (nefc 82 instead of 244 per env). The Newton solver is capped at 3 iterations (5
line-search steps): with frictionless contacts, joint limits and frictionloss it converges in 1-2
iterations, and the cap bounds MJX's batched while-loop (H100, batch 8192: 0.73M physics steps/s with
condim 3 and 6 iterations, 1.26M with condim 1, 1.72M with condim 1 and 3 iterations;
``bench/mjx_variants.py`` at fdbaf1a, docs/performance.md). Collision filtering: ``links.COLLISION_BITS``;
the chest does not collide with the shoulder_yaw capsules, which sit 14 mm inside it when the arms hang
(lite-model.md 4.4).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from functools import cache

import mujoco
import numpy as np

from bar_policy.robot import links
from bar_policy.robot.constants import MODES, POSE_NAMES, RobotSpec, load_robot
from bar_policy.robot.index import RobotIndex

__all__ = ["PHYSICS_DT", "SceneEdit", "compile_scene", "load_model", "robot_spec", "scene_xml"]

PHYSICS_DT = 0.002
"""Physics timestep, s (500 Hz)."""

SceneEdit = Callable[[mujoco.MjSpec], None]
"""A task's additions to the robot's scene: edits the spec in place (adds bodies, sensors, ...)."""

_SITE_RGBA = (1.0, 0.3, 0.3, 1.0)
_SITE_RADIUS = 0.008  # m
_FLOOR_RGBA = (0.85, 0.85, 0.85, 1.0)


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid modes: {list(MODES)}")


def _inertial(body: mujoco.MjsBody, inertial: links.Inertial) -> None:
    body.explicitinertial = True
    body.ipos = inertial.com
    body.mass = inertial.mass
    body.fullinertia = inertial.inertia


def _capsule(body: mujoco.MjsBody, capsule: links.Capsule, group: str, rgba: Sequence[float]) -> None:
    contype, conaffinity = links.COLLISION_BITS[group]
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_CAPSULE,
        size=[capsule.radius, 0.0, 0.0],
        fromto=capsule.fromto,
        contype=contype,
        conaffinity=conaffinity,
        rgba=rgba,
    )


def _chain(
    parent: mujoco.MjsBody,
    chain: Sequence[links.Link],
    robot: RobotSpec,
    colliders: Sequence[links.Capsule],
    group: str,
) -> mujoco.MjsBody:
    """Add a serial chain below ``parent`` (each link the previous one's child); returns the last body."""
    body = parent
    for link in chain:
        body = body.add_body(name=link.name, pos=link.pos)
        _inertial(body, link.inertial)
        j = robot.joints[robot.index(links.JOINT_OF_BODY.get(link.name, link.name))]
        body.add_joint(
            name=j.name,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=link.axis,
            range=[j.lower, j.upper],
            armature=j.armature,
            frictionloss=j.frictionloss,
            actfrcrange=[-j.sim_effort, j.sim_effort],
        )
        for c in colliders:
            if c.body == link.name:
                _capsule(body, c, group, links.ARM_RGBA)
    return body


def _fingertip(hand: mujoco.MjsBody, name: str) -> None:
    hand.add_site(
        name=name,
        pos=links.FINGERTIP_SITE_POS[name],
        size=[_SITE_RADIUS, 0.005, 0.005],  # MuJoCo's default site size after the radius
        rgba=_SITE_RGBA,
    )


def robot_spec(mode: str = "arms") -> mujoco.MjSpec:
    """A fresh ``MjSpec`` of the Lite alone for ``mode`` (``arms`` or ``arms_neck``), not yet compiled.

    Holds the options, the world (light, floor, ``front`` camera), the chest and its chains, the contact
    exclusions and one ``motor`` actuator per joint in canonical order. The named poses are not in it:
    ``compile_scene`` adds them as keyframes once the scene's joints are known. A task may edit the
    returned spec freely before compiling it.
    """
    _check_mode(mode)
    robot = load_robot(mode)
    spec = mujoco.MjSpec()
    spec.modelname = f"lite_dummy_{mode}"
    spec.compiler.degree = False
    spec.compiler.autolimits = True
    spec.option.timestep = PHYSICS_DT
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.iterations = 3
    spec.option.ls_iterations = 5
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    spec.default.geom.condim = 1  # the main class: before any geom is added

    world = spec.worldbody
    world.add_light(pos=[0.6, 0, 1.5], dir=[-0.4, 0, -1])
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[1, 1, 0.05],
        rgba=_FLOOR_RGBA,
        contype=0,
        conaffinity=0,
    )
    cam = world.add_camera(name="front", pos=[1.3, 0, 0.55])
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_XYAXES
    cam.alt.xyaxes = [0, 1, 0, -0.25, 0, 1]

    chest = world.add_body(name="chest", pos=[0, 0, 0])
    _inertial(chest, links.CHEST)
    torso_ct, torso_ca = links.COLLISION_BITS["torso"]
    _capsule(chest, links.CHEST_CAPSULE, "torso", links.TORSO_RGBA)
    for box in links.CHEST_BOXES:
        chest.add_geom(
            type=mujoco.mjtGeom.mjGEOM_BOX,
            size=box.half_size,
            pos=box.pos,
            quat=box.quat,
            contype=torso_ct,
            conaffinity=torso_ca,
            rgba=links.TORSO_RGBA,
        )
    left_hand = _chain(chest, links.LEFT_ARM, robot, links.LEFT_COLLIDERS, "left")
    _fingertip(left_hand, "left_finger2_tip")
    right_hand = _chain(chest, links.RIGHT_ARM, robot, links.RIGHT_COLLIDERS, "right")
    _fingertip(right_hand, "right_finger2_tip")
    if mode == "arms_neck":
        # No head collider here: the text-template MJCF meant to add ``links.HEAD_CAPSULE`` but never
        # did (its text substitution did not match), and the compiled model stays as it was.
        _chain(chest, links.NECK, robot, (), "torso")
    else:
        head = chest.add_body(name="head", pos=[0, 0, 0])  # neck and head lumped, fixed to the chest
        _inertial(head, links.HEAD_LUMPED)
        _capsule(head, links.HEAD_LUMPED_CAPSULE, "torso", links.TORSO_RGBA)

    spec.add_exclude(bodyname1="chest", bodyname2="left_shoulder_yaw")
    spec.add_exclude(bodyname1="chest", bodyname2="right_shoulder_yaw")
    for j in robot.joints:
        act = spec.add_actuator(
            name=j.name,
            target=j.name,
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            ctrlrange=[-j.sim_effort, j.sim_effort],
            forcerange=[-j.sim_effort, j.sim_effort],
        )
        act.set_to_motor()
    return spec


def compile_scene(spec: mujoco.MjSpec, mode: str = "arms") -> mujoco.MjModel:
    """Compile a scene built on ``robot_spec(mode)``, with the robot's named poses as keyframes.

    Each pose of ``POSE_NAMES`` becomes a keyframe of that name: the robot's joints at the pose, every
    other coordinate at the scene's ``qpos0`` (a keyframe needs all ``nq`` of them, which are known only
    once the task's joints are in). So the spec is compiled twice; keyframes of those names already in
    ``spec`` (a second call) are replaced.

    Raises:
        ValueError: the scene lacks one of the robot's joints (``RobotIndex.from_model``).
    """
    _check_mode(mode)
    robot = load_robot(mode)
    for name in POSE_NAMES:
        key = spec.key(name)
        if key is not None:
            spec.delete(key)
    model = spec.compile()
    index = RobotIndex.from_model(model, robot.joint_names)
    for name in POSE_NAMES:
        qpos = np.array(model.qpos0)
        qpos[index.qpos] = robot.pose(name)
        spec.add_key(name=name, qpos=qpos.tolist())
    return spec.compile()


@cache
def _robot_alone(mode: str) -> mujoco.MjModel:
    return compile_scene(robot_spec(mode), mode)


def load_model(mode: str = "arms", scene: SceneEdit | None = None) -> mujoco.MjModel:
    """The compiled scene of ``mode``: the robot, plus what ``scene`` adds to its spec.

    Returns a fresh model each call (callers may mutate it); the robot alone is compiled once per mode
    and copied.
    """
    if scene is None:
        return copy.deepcopy(_robot_alone(mode))
    spec = robot_spec(mode)
    scene(spec)
    return compile_scene(spec, mode)


def scene_xml(mode: str = "arms", scene: SceneEdit | None = None) -> str:
    """MJCF text of the scene (the robot plus ``scene``'s edits, keyframes included), for a log or a viewer.

    Written by MuJoCo's own writer (``MjSpec.to_xml``), which prints 6 significant digits: a model compiled
    from it differs from ``load_model``'s in the last digits, so simulate with ``load_model``.
    """
    spec = robot_spec(mode)
    if scene is not None:
        scene(spec)
    compile_scene(spec, mode)
    return spec.to_xml()
