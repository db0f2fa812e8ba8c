"""The reach workspace: every corner of both target boxes is reachable inside the env's action range."""

from __future__ import annotations

import itertools

import mujoco
import numpy as np
import pytest

from bar_policy.robot.constants import FINGERTIP_SITES, load_robot
from bar_policy.robot.mjcf import load_model
from bar_policy.tasks.reach import ReachTargetConfig, sample_targets
from bar_policy.tasks.reach.env import default_config

GRAVITY_SAG_MARGIN = 0.15
"""rad kept in reserve: with Kp = 50 N m/rad the shoulders sag ~0.05 rad under gravity, so the policy must be
able to command past the IK solution."""


def _ik(m, d, robot, q0, target, side, scale, iters=300):
    """Damped least-squares IK of one arm with q clipped to [q0 - scale, q0 + scale] and the joint limits."""
    idx = np.arange(7) + 7 * side
    lo, hi = np.maximum(robot.lower, q0 - scale), np.minimum(robot.upper, q0 + scale)
    q = q0.copy()
    sid = m.site(FINGERTIP_SITES[side]).id
    jac = np.zeros((3, m.nv))
    for _ in range(iters):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        err = target - d.site_xpos[sid]
        if np.linalg.norm(err) < 1e-4:
            break
        mujoco.mj_jacSite(m, d, jac, None, sid)
        J = jac[:, idx]
        q[idx] = np.clip(q[idx] + J.T @ np.linalg.solve(J @ J.T + 1e-4 * np.eye(3), err), lo[idx], hi[idx])
    d.qpos[:] = q
    mujoco.mj_forward(m, d)
    return float(np.linalg.norm(target - d.site_xpos[sid])), d.ncon


def test_every_box_corner_reachable_within_action_scale():
    cfg = default_config()
    robot = load_robot("arms")
    m = load_model("arms")
    d = mujoco.MjData(m)
    q0 = robot.pose("piano_ready")
    box = cfg.target
    scale = cfg.action_scale - GRAVITY_SAG_MARGIN  # 0.65 rad
    for side in (0, 1):
        mirror = np.array([1.0, -1.0, 1.0]) if side else np.ones(3)
        for corner in itertools.product(*zip(box.low, box.high, strict=True)):
            err, ncon = _ik(m, d, robot, q0, np.array(corner) * mirror, side, scale)
            assert err < 1e-3, (side, corner, err)
            assert ncon == 0, (side, corner)  # no self-collision at the reaching pose


@pytest.mark.numerics
def test_sample_targets_numpy_and_jax_agree():
    jnp = pytest.importorskip("jax.numpy")
    u = np.random.default_rng(0).random((64, 6)).astype(np.float32)
    cfg = ReachTargetConfig()
    ln, rn = sample_targets(u, cfg)
    lj, rj = sample_targets(jnp.asarray(u), cfg)
    # low + u * (high - low) in m, |x| <= 0.8: three float32 roundings of eps32 * 0.8 = 9.5e-8 <= 1e-6.
    np.testing.assert_allclose(ln, lj, atol=1e-6)
    np.testing.assert_allclose(rn, rj, atol=1e-6)
    # u = 0 -> the low corner; the right target mirrors y.
    left, right = sample_targets(np.zeros(6), cfg)
    np.testing.assert_allclose(left, cfg.low)
    np.testing.assert_allclose(right, cfg.low * np.array([1.0, -1.0, 1.0]))


def test_target_config_validation():
    with pytest.raises(ValueError, match="x_range"):
        ReachTargetConfig(x_range=(0.5, 0.2))
    with pytest.raises(ValueError, match="overlap"):
        ReachTargetConfig(y_range=(0.0, 0.3))
