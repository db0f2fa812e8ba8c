"""LiteReach: registry, config validation, jit reset/step, observation layout and step semantics."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from env_support import BATCH

from bar_policy import envs
from bar_policy.obs import ObservationManager
from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.mjcf import load_model
from bar_policy.tasks.reach import ReachTargetConfig


def test_registry_and_errors():
    assert "LiteReach" in envs.ALL_ENVS
    with pytest.raises(ValueError, match="available envs"):
        envs.load("Nope")
    cfg = envs.apply_overrides(
        envs.default_config("LiteReach"),
        ["reward.scales.action_rate=-0.02", "actuator.latency_steps=[0, 1]", "episode_length_s=6"],
    )
    assert cfg.reward.scales.action_rate == -0.02
    assert cfg.actuator.latency_steps == (0, 1)
    assert cfg.episode_length_s == 6.0 and cfg.episode_length == 300
    with pytest.raises(ValueError, match="fields"):
        envs.apply_overrides(cfg, ["reward.scales.nope=1"])
    with pytest.raises(ValueError, match="valid modes"):
        envs.apply_overrides(cfg, ["mode=legs"])
    with pytest.raises(ValueError, match="multiple"):
        envs.apply_overrides(cfg, ["ctrl_dt=0.003"])
    with pytest.raises(ValueError, match="latency_steps"):
        envs.apply_overrides(cfg, ["actuator.latency_steps=[2, 1]"])
    with pytest.raises(ValueError, match="damping"):
        envs.apply_overrides(cfg, ["actuator.damping=rk4"])
    with pytest.raises(ValueError, match=r"fingertip_kinematics 'fk'; valid: \['chains', 'mjx'\]"):
        envs.apply_overrides(cfg, ["fingertip_kinematics=fk"])
    assert envs.apply_overrides(cfg, ["fingertip_kinematics=mjx"]).fingertip_kinematics == "mjx"


def test_metadata_arrays(nominal_env):
    env = nominal_env
    robot = load_robot("arms")
    assert env.action_size == 14 and env.n_substeps == 10 and env.dt == pytest.approx(0.02)
    assert env.episode_length == 250
    np.testing.assert_allclose(env.default_pose, robot.pose("piano_ready"), atol=1e-7)
    np.testing.assert_allclose(env.action_scale, 0.8)
    np.testing.assert_array_equal(env.kp, robot.kp)
    np.testing.assert_array_equal(env.kd, robot.kd)


def test_q_command_hand_values(nominal_env):
    env = nominal_env
    q = np.asarray(env.q_command(jnp.ones(14)))
    # left_shoulder_pitch: 0.3 + 0.8 = 1.1 -> clipped to its upper limit pi/4.
    assert q[0] == pytest.approx(np.pi / 4, abs=1e-6)
    # left_elbow_pitch: -1.7 + 0.8 = -0.9 (inside [-2.356, 0]).
    assert q[3] == pytest.approx(-0.9, abs=1e-6)
    # actions beyond [-1, 1] are clipped first: 5 acts like 1.
    np.testing.assert_array_equal(env.q_command(jnp.full(14, 5.0)), q)
    np.testing.assert_allclose(env.q_command(jnp.zeros(14)), env.default_pose, atol=1e-7)


@pytest.mark.numerics
def test_reset_obs_matches_schema_and_c_kinematics(nominal_env, nominal_fns):
    env = nominal_env
    reset, _ = nominal_fns
    s = reset(jax.random.PRNGKey(0))
    om = ObservationManager.for_task("reach", "arms")
    assert env.observation_size == om.size == 54
    assert s.obs.shape == (54,) and s.obs.dtype == jnp.float32
    parts = om.split(np.asarray(s.obs))
    # Nominal: q0 = default pose, no offset or noise, so q - default is 0 up to one float32 rounding of
    # |q| <= pi (ulp 2.4e-7); 1e-6 = 4 ulps.
    np.testing.assert_allclose(parts["joint_pos"], 0.0, atol=1e-6)
    np.testing.assert_array_equal(parts["actions"], 0.0)
    # Fingertips equal C MuJoCo forward kinematics at piano_ready (chest = world frame).
    m = load_model("arms")
    d = mujoco.MjData(m)
    d.qpos[:] = load_robot("arms").pose("piano_ready")
    mujoco.mj_kinematics(m, d)
    for side, site in zip(("left", "right"), FINGERTIP_SITES, strict=True):
        # float32 MJX vs float64 C: 8 bodies to the fingertip, ~10 roundings each at |x| <= 0.75 m
        # (eps32 * 0.75 = 9e-8): 80 * 9e-8 = 7e-6 <= 1e-5.
        np.testing.assert_allclose(parts[f"fingertip_pos_{side}"], d.site(site).xpos, atol=1e-5)
    # Targets inside the workspace boxes (right box mirrored in y).
    box = ReachTargetConfig()
    tl, tr = parts["target_pos_left"], parts["target_pos_right"]
    assert np.all(tl >= box.low - 1e-6) and np.all(tl <= box.high + 1e-6)
    mirror = np.array([1.0, -1.0, 1.0])
    assert np.all(tr * mirror >= box.low - 1e-6) and np.all(tr * mirror <= box.high + 1e-6)


def test_step_reward_metrics_and_resampling(nominal_env, nominal_fns):
    env = nominal_env
    reset, step = nominal_fns
    s = reset(jax.random.PRNGKey(1))
    a = jnp.full(14, 0.25, jnp.float32)  # strong dtype: the same compiled step as a policy action
    s1 = step(s, a)
    # The reward is the sum of the logged, scaled terms.
    terms = {k: float(v) for k, v in s1.metrics.items() if k.startswith("reward/")}
    assert set(terms) == {f"reward/{n}" for n in env.reward_names}
    assert float(s1.reward) == pytest.approx(sum(terms.values()), rel=1e-5, abs=1e-6)
    # The 3 Hz action filter from the reset's zero action: applied = alpha * 0.25, alpha = 1 - exp(-2 pi 3
    # 0.02) = 0.3141. action_rate = 14 * applied^2 (weight -0.1); action_accel has a_{t-1} = a_{t-2} = 0,
    # so the same sum (weight -0.2).
    assert env.config.action_filter_hz == 3.0
    applied = (1.0 - np.exp(-2.0 * np.pi * 3.0 * 0.02)) * 0.25
    assert terms["reward/action_rate"] == pytest.approx(-0.1 * 14 * applied**2, rel=1e-5)
    assert terms["reward/action_accel"] == pytest.approx(-0.2 * 14 * applied**2, rel=1e-5)
    # wrist_posture = -0.1 sum |q - q_default| over the six wrist joints, read from qpos at the compiled
    # model's joint addresses, against the reference's piano_ready pose (the reach default; float32 q of
    # order 1: 1e-6 is 8 ulp per joint).
    wrists = [n for n in env.robot.joint_names if "wrist" in n]
    assert len(wrists) == 6
    qpos, q0 = np.asarray(s1.data.qpos), env.robot.pose("piano_ready")
    dev = sum(abs(qpos[env.mj_model.joint(n).qposadr[0]] - q0[env.robot.index(n)]) for n in wrists)
    assert dev > 1e-3  # the action moved the wrists, so the check is not 0 == 0
    assert terms["reward/wrist_posture"] == pytest.approx(-0.1 * dev, abs=1e-6)
    # The previous-action slice of the obs is the action just applied (float32: 1e-7 on 0.0785).
    om = env.obs_manager
    np.testing.assert_allclose(om.split(np.asarray(s1.obs))["actions"], applied, atol=1e-7)
    # dist metrics = |fingertip - target| from the site positions.
    tips = np.asarray(s1.data.site_xpos)
    assert float(s1.metrics["dist_left"]) == pytest.approx(
        np.linalg.norm(tips[0] - np.asarray(s.info["target_left"])), abs=1e-5
    )
    assert float(s1.done) == 0.0
    # The commanded target starts at the default pose's fingertips (C MuJoCo FK, tolerance as above) and
    # moves to the segment's goal along 10 s^3 - 15 s^4 + 6 s^5, s = k dt / 1 s after step k; the goal
    # stays for resample_steps - 1 steps and changes on the resample step, where the next move starts from
    # the commanded target (elapsed 0: target = from exactly).
    assert env.config.target_transition_s == 1.0
    m = load_model("arms")
    d = mujoco.MjData(m)
    d.qpos[:] = load_robot("arms").pose("piano_ready")
    mujoco.mj_kinematics(m, d)
    tips0 = d.site(FINGERTIP_SITES[0]).xpos.copy()
    np.testing.assert_allclose(s.info["target_left"], tips0, atol=1e-5)
    goal = np.asarray(s.info["goal_left"], dtype=np.float64)
    start = np.asarray(s.info["from_left"], dtype=np.float64)
    seen = {}
    for k in range(2, env.config.resample_steps):
        s1 = step(s1, a)
        seen[k] = np.asarray(s1.info["target_left"], dtype=np.float64)
        np.testing.assert_array_equal(s1.info["goal_left"], goal.astype(np.float32))
    for k in (2, 10, 25, 40, 50, 80, env.config.resample_steps - 1):
        ph = min(k * 0.02, 1.0)
        expected = start + (goal - start) * (10 * ph**3 - 15 * ph**4 + 6 * ph**5)
        # float32: |x| <= 0.42 m, a handful of roundings of eps32 * 0.42 = 5e-8 each: 1e-6 covers them.
        np.testing.assert_allclose(seen[k], expected, atol=1e-6)
    np.testing.assert_allclose(seen[25], (start + goal) / 2, atol=1e-6)  # min_jerk(1/2) = 1/2 by symmetry
    assert float(s1.metrics["segment_end"]) == 0.0
    last = np.asarray(s1.info["target_left"])
    s1 = step(s1, a)
    assert int(s1.info["step"]) == env.config.resample_steps
    assert float(s1.metrics["segment_end"]) == 1.0
    assert not np.allclose(s1.info["goal_left"], goal)
    np.testing.assert_array_equal(s1.info["from_left"], last)
    np.testing.assert_array_equal(s1.info["target_left"], last)


def test_step_keeps_state_types(nominal_fns, wrapped):
    """step(state) has exactly the state's structure, shapes, dtypes and weak types: no recompiles.

    (Uses the fixtures' jitted functions, whose traces are cached, so this costs no extra tracing.)
    """

    def same(a, b):
        la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
        assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
        for x, y in zip(la, lb, strict=True):
            assert (x.shape, x.dtype, x.weak_type) == (y.shape, y.dtype, y.weak_type)

    reset, step = nominal_fns
    s = jax.eval_shape(reset, jax.random.PRNGKey(0))
    same(s, jax.eval_shape(step, s, jnp.zeros(14, jnp.float32)))
    _, wreset, wstep = wrapped
    keys = jax.random.split(jax.random.PRNGKey(0), BATCH)
    ws = jax.eval_shape(wreset, keys)
    same(ws, jax.eval_shape(wstep, ws, jnp.zeros((BATCH, 14), jnp.float32)))


def test_neck_mode_obs_size():
    cfg = dataclasses.replace(envs.nominal_config(), mode="arms_neck")
    env = envs.load("LiteReach", config=cfg)
    assert env.action_size == 17
    assert env.observation_size == ObservationManager.for_task("reach", "arms_neck").size
    s = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    assert s.obs.shape == (env.observation_size,)


def test_task_is_solvable_through_the_action_interface(nominal_env, nominal_fns):
    """An oracle (C MuJoCo IK + integral action on the joint error) reaches both targets: success = 1.

    Kp = 50 N m/rad lets the shoulders sag ~0.05 rad under gravity, so a policy must command past the IK
    solution; the integral term does that here, inside the action range.
    """
    env = nominal_env
    reset, step = nominal_fns
    s = reset(jax.random.PRNGKey(7))
    m = load_model("arms")
    d = mujoco.MjData(m)
    q_star = env.default_pose.astype(np.float64)
    jac = np.zeros((3, m.nv))
    for side, key in ((0, "goal_left"), (1, "goal_right")):  # the segment goal: the target after 1 s
        idx = np.arange(7) + 7 * side
        sid = m.site(FINGERTIP_SITES[side]).id
        target = np.asarray(s.info[key], np.float64)
        for _ in range(300):
            d.qpos[:] = q_star
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jac, None, sid)
            J = jac[:, idx]
            err = target - d.site_xpos[sid]
            q_star[idx] += J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(3), err)
    a = (q_star - env.default_pose) / env.action_scale
    for _ in range(120):  # 2.4 s, before the resample at 2.5 s
        s = step(s, jnp.asarray(np.clip(a, -1, 1), jnp.float32))
        a = a + 0.1 * (q_star - np.asarray(s.data.qpos)) / env.action_scale
    assert float(s.metrics["success"]) == 1.0, (float(s.metrics["dist_left"]), float(s.metrics["dist_right"]))
    assert float(s.metrics["reward/reach_fine"]) > 0.5
