"""The MJX env in a task's scene (tests/scene_support.py: a key on a spring, a pendulum on the left hand whose
coordinate sits between the arms'): it steps like the C MuJoCo sim target in the same scene, observes the
robot's own joints, and the model randomiser writes only the robot's dofs.

``KeyReach`` is reach's task in that scene, unchanged: reach reads the robot's coordinates through the
env's addresses (``robot_q``/``robot_dq``) and computes the fingertips through ``with_robot_q``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scene_support import EXTRA_JOINTS, key_scene

from bar_policy import envs
from bar_policy.deploy.targets.sim import SimConfig, SimTarget
from bar_policy.envs.randomize import armature_bounds, make_randomizer
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mit import MitCommand
from bar_policy.tasks.reach.env import LiteReach, ReachEnvConfig, default_config

STEPS = 15  # control steps, 0.3 s


class KeyReach(LiteReach):
    """LiteReach in the key scene: reach addresses the robot's joints by name; the scene is all it needs."""

    def __init__(self, config: ReachEnvConfig) -> None:
        super().__init__(config, scene=key_scene)


@pytest.fixture(scope="module")
def scene_env() -> KeyReach:
    return KeyReach(envs.nominal_config())


@pytest.mark.numerics
def test_env_in_a_scene_steps_like_the_sim_target(scene_env: KeyReach) -> None:
    """Float32 MJX against the float64 C sim target in the same scene, fed the commands of the actions the
    env applied. Tolerance as the robot-alone parity test (tests/envs/test_physics.py): 1e-3 rad, where
    one 16-bit LSB of q_cmd is 3.8e-4 rad and float32 rounding can flip it."""
    env = scene_env
    index = env.robot_index
    m = env.mj_model
    extra = [m.joint(name).qposadr[0] for name in EXTRA_JOINTS]
    assert not index.robot_only and m.nq == env.action_size + len(extra)
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    s = reset(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(np.asarray(env.robot_q(s.data)), env.default_pose)  # init_noise 0
    np.testing.assert_array_equal(np.asarray(s.data.qpos)[extra], 0.0)  # the scene's joints at qpos0

    sim = SimTarget("arms", SimConfig(damping=env.config.actuator.damping), scene=key_scene)
    sim.reset(q=env.default_pose.astype(np.float64))
    kp, kd = env.kp.astype(np.float64), env.kd.astype(np.float64)
    t = np.arange(STEPS)[:, None] * env.dt
    actions = 0.8 * np.sin(2 * np.pi * 2.0 * t + np.linspace(0, np.pi, env.action_size)[None])
    q_err = []
    for a in actions.astype(np.float32):
        s = step(s, jnp.asarray(a))
        applied = s.info["last_act"]
        q_cmd = np.asarray(env.q_command(applied), dtype=np.float64)
        sim.write_command(MitCommand.position(q_cmd, kp, kd))
        sim.advance(env.dt)
        q_err.append(np.abs(np.asarray(env.robot_q(s.data)) - sim.read_state().q).max())
    qpos = np.asarray(s.data.qpos)
    extra_err = np.abs(qpos[extra] - sim.data.qpos[extra]).max()
    # Measured on CPU: 2.1e-4 rad on the robot, 2.7e-5 rad on the key and the pendulum.
    print(f"scene parity: max robot q err {max(q_err):.2e} rad, scene joints {extra_err:.2e} rad")
    assert max(q_err) < 1e-3, q_err
    assert extra_err < 1e-3
    assert np.abs(qpos[index.qpos] - env.default_pose).max() > 0.05  # the arms did move

    # The observation is the robot's: its joints at their addresses and the fingertips of those joints
    # (float64 C kinematics of the robot alone; float32 rounding of positions below 1 m: 1e-6).
    q, dq = np.asarray(env.robot_q(s.data)), np.asarray(env.robot_dq(s.data))
    left, right = Kinematics("arms").fingertips(q.astype(np.float64))
    inputs = {
        "joint_pos": q,
        "joint_vel": dq,
        "actions": np.asarray(s.info["last_act"]),
        "fingertip_pos_left": left,
        "fingertip_pos_right": right,
        "target_pos_left": np.asarray(s.info["target_left"]),
        "target_pos_right": np.asarray(s.info["target_right"]),
    }
    np.testing.assert_allclose(np.asarray(s.obs), env.obs_manager.compute(inputs), rtol=0, atol=1e-5)
    assert np.isfinite(np.asarray(s.reward)) and float(s.done) == 0.0


def test_randomizer_writes_only_the_robot_dofs(scene_env: KeyReach) -> None:
    cfg = default_config()  # armature and friction randomised
    model = scene_env.mjx_model
    index = scene_env.robot_index
    batch, _ = make_randomizer(cfg)(model, jax.random.split(jax.random.PRNGKey(3), 2))
    other = np.setdiff1d(np.arange(model.nv), index.dof)
    lo, hi = armature_bounds(cfg.mode)
    f_lo, f_hi = cfg.randomization.frictionloss
    for field in ("dof_armature", "dof_frictionloss"):
        values = np.asarray(getattr(batch, field))
        assert values.shape == (2, model.nv)
        np.testing.assert_array_equal(
            values[:, other], np.broadcast_to(getattr(model, field)[other], (2, len(other)))
        )
    arm = np.asarray(batch.dof_armature)[:, index.dof]
    assert np.all((arm >= lo.astype(np.float32)) & (arm <= hi.astype(np.float32)))
    fric = np.asarray(batch.dof_frictionloss)[:, index.dof]
    assert np.all((fric >= f_lo) & (fric <= f_hi))
