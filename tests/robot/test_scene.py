"""The robot's scene from ``mujoco.MjSpec``: the same compiled model as the first (text-template) MJCF, and
a scene with a task's bodies (tests/scene_support.py) on the C side: addresses, keyframes, kinematics,
fingertip-key contact, the sim target and the bus emulator.

tests/data/lite_<mode>.xml are the MJCF texts the template builder (``bar_policy/robot/mjcf.py`` up to
commit 8c508c3, ``lite_xml(mode)``) wrote, stored verbatim. The MjSpec build must compile to the very
same model: every numpy array of ``mujoco.MjModel``, every integer, float and bytes attribute (sizes,
``names``, ``signature``) and every field of ``opt``, ``vis`` and ``stat``, compared exactly. Exact,
not within a tolerance: the spec is given the same float64 numbers the XML parser reads from the decimal
text (Python's ``float`` literals and MuJoCo's ``strtod`` both round correctly), in the same order, so
the compiler runs the same arithmetic on the same inputs.

A deliberate change of the robot (new link numbers, a joint property) fails this test; then make the same
change to the reference MJCF text in the same commit and say why (``MjSpec.to_xml`` is no substitute: it
writes 6 significant digits).
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest
from scene_support import (
    EXTRA_JOINTS,
    KEY_DAMPING,
    KEY_HALF,
    KEY_JOINT,
    KEY_MASS,
    KEY_SENSOR,
    KEY_SITE,
    KEY_STIFFNESS,
    PENDULUM_JOINT,
    key_scene,
)

from bar_policy.deploy.targets.sim import SimConfig, SimTarget
from bar_policy.robot.constants import MODES, POSE_NAMES, load_robot
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mit import MitCommand, firmware_torque, quantize_command, wire_ranges
from bar_policy.robot.scene import compile_scene, load_model, robot_spec
from bar_policy.robstride.emulator import RobstrideEmulator
from tests.robstride.helpers import command_position

REFERENCE = Path(__file__).parents[1] / "data"


def _fields(obj: Any, prefix: str = "", depth: int = 0) -> dict[str, Any]:
    """Public numeric data of a MuJoCo struct: arrays, numbers and bytes, recursing into sub-structs."""
    out: dict[str, Any] = {}
    for name in dir(obj):
        if name.startswith("_"):
            continue
        value = getattr(obj, name)
        key = f"{prefix}{name}"
        if isinstance(value, np.ndarray | int | float | bytes):
            out[key] = value
        elif type(value).__module__.startswith("mujoco") and not callable(value) and depth < 2:
            out.update(_fields(value, f"{key}.", depth + 1))
    return out


@pytest.mark.parametrize("mode", MODES)
def test_spec_model_equals_text_template_model(mode: str) -> None:
    ref = _fields(mujoco.MjModel.from_xml_path(str(REFERENCE / f"lite_{mode}.xml")))
    new = _fields(load_model(mode))
    assert ref.keys() == new.keys()
    # The comparison covers the model's arrays, its names and its options (not an empty walk).
    covered = {"body_mass", "jnt_range", "key_qpos", "names", "opt.timestep", "vis.global_.offwidth"}
    assert covered <= ref.keys()
    differ = []
    for key, a in ref.items():
        b = new[key]
        if isinstance(a, np.ndarray):
            nan = a.dtype.kind == "f"
            same = a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=nan)
        else:
            same = a == b
        if not same:
            differ.append(key)
    assert not differ, f"{mode}: fields differ from the text-template model: {differ}"


# -- a task's scene -----------------------------------------------------------------------------------
ROBOT = load_robot("arms")
EXTRA = EXTRA_JOINTS
_channel = itertools.count()


@pytest.mark.parametrize("mode", MODES)
def test_robot_alone_addresses_are_the_first_coordinates(mode: str) -> None:
    # The robot alone compiles its joints and motors in canonical order (tests/test_mjcf.py checks the
    # names), so the addresses are 0..n-1 and the env may use qpos and qvel as they are.
    m, n = load_model(mode), load_robot(mode).num_joints
    index = RobotIndex.from_model(m, load_robot(mode).joint_names)
    for addresses in (index.qpos, index.dof, index.actuator):
        np.testing.assert_array_equal(addresses, np.arange(n))
    assert index.robot_only


def test_scene_holds_the_task_additions_and_the_robot_by_name() -> None:
    m = load_model("arms", key_scene)
    index = RobotIndex.from_model(m, ROBOT.joint_names)
    n = ROBOT.num_joints
    assert m.nq == m.nv == n + len(EXTRA) and m.nu == n
    assert m.site(KEY_SITE).id >= 0 and m.sensor(KEY_SENSOR).dim[0] == 1
    # The pendulum's hinge hangs below the left hand: depth first, it comes between the two arms.
    assert m.joint(PENDULUM_JOINT).qposadr[0] == 7
    assert not index.robot_only
    extra = {int(m.joint(j).qposadr[0]) for j in EXTRA}
    assert extra.isdisjoint(index.qpos.tolist()) and len(set(index.qpos.tolist())) == n
    # Writing q through the addresses puts each value on the joint of its name (MuJoCo's own accessor).
    d = mujoco.MjData(m)
    q = np.random.default_rng(1).uniform(ROBOT.lower, ROBOT.upper)
    d.qpos[index.qpos] = q
    np.testing.assert_array_equal([d.joint(name).qpos[0] for name in ROBOT.joint_names], q)
    np.testing.assert_array_equal(index.q(d.qpos), q)
    # Each robot actuator drives the joint of its name.
    assert [m.joint(m.actuator_trnid[a, 0]).name for a in index.actuator] == list(ROBOT.joint_names)


def test_keyframes_put_the_robot_in_its_poses_and_the_rest_at_qpos0() -> None:
    m = load_model("arms", key_scene)
    index = RobotIndex.from_model(m, ROBOT.joint_names)
    others = np.setdiff1d(np.arange(m.nq), index.qpos)
    for name in POSE_NAMES:
        qpos = m.key(name).qpos
        np.testing.assert_array_equal(qpos[index.qpos], ROBOT.pose(name))
        np.testing.assert_array_equal(qpos[others], m.qpos0[others])
    # Compiling a spec a second time replaces the robot's keyframes instead of adding duplicates.
    spec = robot_spec("arms")
    key_scene(spec)
    compile_scene(spec, "arms")
    assert compile_scene(spec, "arms").nkey == len(POSE_NAMES)


def test_missing_robot_joint_is_refused() -> None:
    def drop_elbow(spec: mujoco.MjSpec) -> None:
        spec.delete(spec.actuator("left_elbow_pitch"))
        spec.delete(spec.joint("left_elbow_pitch"))

    with pytest.raises(ValueError, match=r"lacks the robot's joints \['left_elbow_pitch'\]"):
        load_model("arms", drop_elbow)


def test_kinematics_in_the_scene_equal_the_robot_alone() -> None:
    alone, scene = Kinematics("arms"), Kinematics("arms", key_scene)
    rng = np.random.default_rng(0)
    for q in rng.uniform(ROBOT.lower, ROBOT.upper, (20, ROBOT.num_joints)):
        # The tasks' bodies hang off the world and the hand, never between a fingertip and the chest: the
        # same float64 arithmetic along each chain, so exactly equal.
        for a, b in zip(alone.fingertips(q), scene.fingertips(q), strict=True):
            np.testing.assert_array_equal(a, b)
    pose = ROBOT.pose("piano_ready")
    assert alone.collisions(pose) == scene.collisions(pose) == []  # the key sits clear of both hands


def test_a_key_under_the_fingertip_touches_the_finger() -> None:
    """The key's collision bits (conaffinity = the arms' contype bits) give fingertip-key contacts."""
    tip = Kinematics("arms").fingertips(ROBOT.pose("piano_ready"))[0]
    # Hinge placed so the key's box (hinge at x = 0, free end at -0.14 m) has its top face 3 mm above the
    # fingertip site, 0.07 m in from the free end: the finger capsule (radius 6 mm, axis ending 1 mm short
    # of the site) reaches into it.
    key_pos = (tip[0] + KEY_HALF[0], tip[1], tip[2] - KEY_HALF[2] + 0.003)
    kin = Kinematics("arms", lambda spec: key_scene(spec, key_pos))
    pairs = {tuple(sorted(p[:2])) for p in kin.collisions(ROBOT.pose("piano_ready"))}
    assert ("left_hand", "test_key") in pairs
    assert all("right" not in a + b and "chest" not in a + b for a, b in pairs)


def _key_equilibrium(m: mujoco.MjModel) -> float:
    """Rest angle of the key, rad: spring torque balances gravity on its centre (0.07 m out on the free
    side), ``k theta = -m g l cos(theta)``, solved by fixed-point iteration (contraction factor m g l / k =
    0.01)."""
    g, lever = -m.opt.gravity[2], KEY_HALF[0]
    theta = 0.0
    for _ in range(20):
        theta = -KEY_MASS * g * lever * np.cos(theta) / KEY_STIFFNESS
    return theta


def test_sim_target_runs_the_scene_as_a_plain_loop_on_named_joints() -> None:
    """SimTarget in the scene against C MuJoCo stepped by hand, every robot quantity through MuJoCo's
    named joint accessors: the same firmware torque and implicit damping, so the same trajectory."""
    sim = SimTarget("arms", scene=key_scene)
    pose = ROBOT.pose("piano_ready")
    np.testing.assert_array_equal(sim.read_state().q, pose)
    cmd = MitCommand.position(pose + 0.05, ROBOT.kp, ROBOT.kd)
    sim.write_command(cmd)
    sim.advance(0.5)

    m = load_model("arms", key_scene)
    d = mujoco.MjData(m)
    joints = [d.joint(name) for name in ROBOT.joint_names]
    dofs = [m.joint(name).dofadr[0] for name in ROBOT.joint_names]
    for j, q in zip(joints, pose, strict=True):
        j.qpos[0] = q
    ranges = wire_ranges(ROBOT.models)
    wire = quantize_command(cmd, ranges)
    for _ in range(250):
        q = np.array([j.qpos[0] for j in joints])
        dq = np.array([j.qvel[0] for j in joints])
        tau = firmware_torque(wire, q, dq, ranges, ROBOT.torque_cap, quantize_wire=False)
        d_law = np.where(np.abs(tau) < ROBOT.torque_cap, wire.kd, 0.0)
        m.dof_damping[dofs] = d_law
        for j, f in zip(joints, tau + d_law * dq, strict=True):
            j.qfrc_applied[0] = f
        mujoco.mj_step(m, d)
    np.testing.assert_allclose(sim.read_state().q, [j.qpos[0] for j in joints], rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.data.qpos, d.qpos, rtol=0, atol=1e-12)  # the key and pendulum too
    # No actuator force on the scene's own joints; its sensor reads its joint (sensors are evaluated at the
    # start of a step, before integration: recompute them for the present state).
    for name in EXTRA:
        assert sim.data.joint(name).qfrc_applied[0] == 0.0
    mujoco.mj_forward(sim.model, sim.data)
    assert sim.data.sensor(KEY_SENSOR).data[0] == sim.data.joint(KEY_JOINT).qpos[0]


def test_sim_target_key_settles_where_spring_meets_gravity() -> None:
    sim = SimTarget("arms", scene=key_scene)
    sim.write_command(MitCommand.position(ROBOT.pose("piano_ready"), ROBOT.kp, ROBOT.kd))
    # Overdamped (damping ratio c / (2 sqrt(k I)) ~ 1.3 with I ~ 2e-4 kg*m^2): the slow mode decays in ~20
    # ms, so after 1 s only the static balance is left.
    sim.advance(1.0)
    assert KEY_DAMPING > 0
    assert sim.data.joint(KEY_JOINT).qpos[0] == pytest.approx(_key_equilibrium(sim.model), abs=1e-7)


def _emulator_step_in_key_scene(damping: str, target: np.ndarray, steps: int) -> tuple[Any, ...]:
    """The bus emulator in the key scene from piano_ready, every motor enabled and commanded to ``target``
    at the robot's gains, ``steps`` physics steps (the lockstep clock's own stepping, without bus rounds):
    (joint q, scene qpos, the motors' caps)."""
    k = next(_channel)
    channels = {"can0": f"scene-test{k}-can0", "can1": f"scene-test{k}-can1"}
    pose = ROBOT.pose("piano_ready")
    emu = RobstrideEmulator(ROBOT, channels, initial_q=pose, scene=key_scene, damping=damping)
    try:
        np.testing.assert_array_equal(emu.joint_positions(), pose)
        command_position(emu, ROBOT, target)
        with emu._lock:
            emu._step(steps)
        cap = np.array([emu.motor(name).params[0x700B] for name in ROBOT.joint_names])
        return emu.joint_positions(), emu.data.qpos.copy(), cap
    finally:
        emu.close()


def test_emulator_drives_the_robot_joints_of_the_scene() -> None:
    """The bus emulator's physics in the scene against a plain loop on named joints (explicit law: the
    motor-frame torque at the motor's cap, no wire rounding after decoding)."""
    pose = ROBOT.pose("piano_ready")
    target = pose + 0.05
    q_emu, qpos_emu, cap = _emulator_step_in_key_scene("explicit", target, 100)

    m = load_model("arms", key_scene)
    d = mujoco.MjData(m)
    joints = [d.joint(name) for name in ROBOT.joint_names]
    for j, q in zip(joints, pose, strict=True):
        j.qpos[0] = q
    ranges = wire_ranges(ROBOT.models)
    cmd = MitCommand.position(target, ROBOT.kp, ROBOT.kd)
    for _ in range(100):
        q = np.array([j.qpos[0] for j in joints])
        dq = np.array([j.qvel[0] for j in joints])
        tau = firmware_torque(cmd, q, dq, ranges, cap, quantize_wire=False)
        for j, f in zip(joints, tau, strict=True):
            j.qfrc_applied[0] = f
        mujoco.mj_step(m, d)
    # Joint and motor frames differ by the sign ``direction``: the same numbers up to float rounding.
    np.testing.assert_allclose(q_emu, [j.qpos[0] for j in joints], rtol=0, atol=1e-9)
    np.testing.assert_allclose(qpos_emu, d.qpos, rtol=0, atol=1e-9)
    assert np.abs(q_emu - pose).max() > 0.01  # the robot moved towards the target


def test_emulator_integrates_the_damping_as_the_sim_target() -> None:
    """The emulator's default (the law's damping integrated implicitly, the firmware's fast loop) and the
    sim target's implicit path are one treatment: the same scene, command and 100 steps give the same
    joints up to float rounding (the sim target without wire rounding; no motor at its cap, so their caps
    do not enter)."""
    pose = ROBOT.pose("piano_ready")
    target = pose + 0.05
    q_emu, qpos_emu, cap = _emulator_step_in_key_scene("implicit", target, 100)
    sim = SimTarget("arms", SimConfig(quantize_wire=False, damping="implicit"), scene=key_scene)
    sim.reset(pose)
    sim.write_command(MitCommand.position(target, ROBOT.kp, ROBOT.kd))
    peak = 0.0
    for _ in range(100):
        peak = max(peak, float(np.max(np.abs(sim.applied_torque()) / np.minimum(cap, sim.robot.torque_cap))))
        sim.step()
    assert peak < 1.0  # unsaturated throughout: both apply Kd as joint damping on every joint
    np.testing.assert_allclose(q_emu, sim.read_state().q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(qpos_emu, sim.data.qpos, rtol=0, atol=1e-9)
    # Not the explicit update: after 0.2 s the two treatments part by more than the rounding above.
    q_explicit, _, _ = _emulator_step_in_key_scene("explicit", target, 100)
    assert np.abs(q_explicit - q_emu).max() > 1e-6
