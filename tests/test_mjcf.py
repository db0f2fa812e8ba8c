"""The compiled MJCF against the joint table, and forward-kinematics facts from lite-model.md."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from bar_policy.robot import load_robot
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.mjcf import PHYSICS_DT, load_model

MIRROR = np.array([1, -1, -1, 1, -1, 1, -1])  # right = S * left (lite-model.md 1.2)


def _tips(m: mujoco.MjModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = mujoco.MjData(m)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    return d.site(FINGERTIP_SITES[0]).xpos.copy(), d.site(FINGERTIP_SITES[1]).xpos.copy()


@pytest.mark.parametrize("mode", ["arms", "arms_neck"])
def test_model_matches_joint_table(mode: str) -> None:
    robot, m = load_robot(mode), load_model(mode)
    assert m.nq == m.nv == m.nu == robot.num_joints
    assert tuple(m.joint(i).name for i in range(m.njnt)) == robot.joint_names
    assert tuple(m.actuator(i).name for i in range(m.nu)) == robot.joint_names
    assert [m.actuator(i).trnid[0] for i in range(m.nu)] == list(range(m.nu))
    np.testing.assert_allclose(m.jnt_range[:, 0], robot.lower)
    np.testing.assert_allclose(m.jnt_range[:, 1], robot.upper)
    assert m.jnt_limited.all()
    np.testing.assert_allclose(m.dof_armature, robot.armature)
    np.testing.assert_allclose(m.dof_frictionloss, robot.frictionloss)
    np.testing.assert_allclose(m.actuator_forcerange[:, 1], robot.sim_effort)
    np.testing.assert_allclose(m.jnt_actfrcrange[:, 1], robot.sim_effort)
    assert m.opt.timestep == PHYSICS_DT == 0.002
    # Total mass 13.692 kg in both modes (lite-model.md 1.4: the rigid head lumps the neck links).
    assert mujoco.mj_getTotalmass(m) == pytest.approx(13.692, abs=1e-3)


def test_fingertips_at_zero_and_piano_ready() -> None:
    m, robot = load_model("arms"), load_robot("arms")
    left, right = _tips(m, robot.pose("zero"))
    # T-pose: left fingertip at (0.0225, 0.705, 0.397) = shoulder (0, .09, .39) + .12+.08+.055+.135+.225 in y,
    # +0.01-0.01+0.0225 in x, +0.007 in z.
    np.testing.assert_allclose(left, [0.0225, 0.705, 0.397], atol=1e-6)
    np.testing.assert_allclose(right, [0.0225, -0.705, 0.397], atol=1e-6)
    left, right = _tips(m, robot.pose("piano_ready"))
    np.testing.assert_allclose(left, [0.361, 0.159, 0.21], atol=1.5e-3)  # reference rounds to 1 mm
    np.testing.assert_allclose(right, [0.361, -0.159, 0.21], atol=1.5e-3)


def test_mirror_symmetry() -> None:
    m = load_model("arms")
    rng = np.random.default_rng(0)
    robot = load_robot("arms")
    for _ in range(50):
        ql = rng.uniform(robot.lower[:7], robot.upper[:7])
        q = np.concatenate([ql, MIRROR * ql])
        left, right = _tips(m, q)
        np.testing.assert_allclose(right, left * [1, -1, 1], atol=1e-5)


def test_shoulder_axis_tilt_and_wrist_centre() -> None:
    m = load_model("arms")
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    c, s = math.cos(math.radians(10)), math.sin(math.radians(10))
    jid = m.joint("left_shoulder_pitch").id
    np.testing.assert_allclose(d.xaxis[jid], [0, c, s], atol=1e-5)
    np.testing.assert_allclose(d.xaxis[m.joint("right_shoulder_pitch").id], [0, c, -s], atol=1e-5)
    np.testing.assert_allclose(d.body("left_wrist_roll").xpos, [0, 0.48, 0.39], atol=1e-9)


def test_gravity_torque_at_t_pose() -> None:
    # lite-model.md 4.6: at the T-pose the shoulder roll holds 4.73 N*m.
    m = load_model("arms")
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert abs(d.qfrc_bias[m.joint("left_shoulder_roll").id]) == pytest.approx(4.73, abs=0.02)
    assert abs(d.qfrc_bias[m.joint("right_shoulder_roll").id]) == pytest.approx(4.73, abs=0.02)


def test_named_poses_are_keyframes_without_contact() -> None:
    m, robot = load_model("arms"), load_robot("arms")
    d = mujoco.MjData(m)
    for name in ("zero", "arms_hanging", "piano_ready"):
        mujoco.mj_resetDataKeyframe(m, d, m.key(name).id)
        np.testing.assert_array_equal(d.qpos, robot.pose(name))
        mujoco.mj_forward(m, d)
        assert d.ncon == 0, name


def test_collision_filter_arms_vs_each_other() -> None:
    m = load_model("arms")
    d = mujoco.MjData(m)
    # A pose (found by random search, within the limits) where the left hand crosses in front of the
    # chest onto the right upper arm and the head.
    q = [-2.95, -0.64, -1.36, -2.26, 0.17, -0.44, -0.67, 0.46, -1.4, -1.27, -0.07, 0.52, 0.32, 0.1]
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    pairs = {
        tuple(sorted((m.body(m.geom_bodyid[c.geom1]).name, m.body(m.geom_bodyid[c.geom2]).name)))
        for c in d.contact[: d.ncon]
    }
    assert any(a.startswith("left") and b.startswith("right") for a, b in pairs), pairs
    # Links of one arm never collide with each other.
    assert not any(a.split("_")[0] == b.split("_")[0] != "chest" for a, b in pairs)
