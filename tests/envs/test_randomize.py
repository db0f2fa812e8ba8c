"""Randomisation ranges: model-level (randomize.py) and episode-level (sampled at reset)."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from env_support import BATCH

from bar_policy import envs
from bar_policy.envs.randomize import armature_bounds, make_randomizer


def test_model_randomisation_ranges(dr_env):
    cfg = dr_env.config
    model = dr_env.mjx_model
    rand = envs.get_randomizer("LiteReach", cfg)
    n = 2000
    batched, in_axes = jax.jit(rand, static_argnums=())(model, jax.random.split(jax.random.PRNGKey(0), n))
    lo, hi = armature_bounds("arms")
    # Description -> identified: rs-02 0.005 -> 0.01369, rs-00 0.002 -> 0.0149, rs-05 0.002 -> 0.00678.
    np.testing.assert_allclose(lo[:2], [0.005, 0.002])
    np.testing.assert_allclose(hi[:2], [0.01369, 0.0149])
    arm = np.asarray(batched.dof_armature)
    assert arm.shape == (n, 14)
    assert np.all(arm >= lo - 1e-7) and np.all(arm <= hi + 1e-7)
    # The samples fill the range (uniform: min/max within 1% of the width of the ends for n = 2000).
    np.testing.assert_allclose(arm.min(0), lo, atol=0.01 * (hi - lo).max())
    np.testing.assert_allclose(arm.max(0), hi, atol=0.01 * (hi - lo).max())
    fr = np.asarray(batched.dof_frictionloss)
    assert fr.min() >= 0.05 and fr.max() <= 0.35
    movable = np.asarray(model.body_mass) > 0
    r = np.asarray(batched.body_mass)[:, movable] / np.asarray(model.body_mass)[None, movable]
    assert r.min() >= 0.9 - 1e-6 and r.max() <= 1.1 + 1e-6
    # Inertia scales with the same factor as the mass of its body.
    inert = np.asarray(batched.body_inertia)[:, movable] / np.asarray(model.body_inertia)[None, movable]
    np.testing.assert_allclose(inert, np.repeat(r[:, :, None], 3, axis=2), rtol=1e-5)
    # in_axes: 0 exactly on the randomised fields.
    assert in_axes.dof_armature == 0 and in_axes.body_mass == 0 and in_axes.dof_frictionloss == 0
    assert in_axes.dof_damping is None and in_axes.body_pos is None


def test_model_randomisation_switches_and_errors(dr_env):
    rand = make_randomizer(envs.nominal_config())
    _, in_axes = rand(dr_env.mjx_model, jax.random.split(jax.random.PRNGKey(0), 4))
    assert all(x is None for x in jax.tree_util.tree_leaves(in_axes, is_leaf=lambda x: x is None))
    with pytest.raises(ValueError, match="shape"):
        rand(dr_env.mjx_model, jax.random.PRNGKey(0))


def test_episode_randomisation_ranges(dr_env, wrapped):
    env = dr_env
    _, reset, _ = wrapped  # reuse the compiled batched reset: 64 calls x 8 envs = 512 episodes
    batches = [reset(jax.random.split(jax.random.PRNGKey(i), BATCH)) for i in range(64)]
    info = {k: np.concatenate([np.asarray(b.info[k]) for b in batches]) for k in ("latency", "kp", "kd")}
    info["encoder_offset"] = np.concatenate([np.asarray(b.info["encoder_offset"]) for b in batches])
    qpos = np.concatenate([np.asarray(b.data.qpos) for b in batches])
    qvel = np.concatenate([np.asarray(b.data.qvel) for b in batches])
    act = env.config.actuator
    assert set(np.unique(info["latency"])) == {0, 1, 2}
    kp_ratio = info["kp"] / env.kp
    kd_ratio = info["kd"] / env.kd
    assert kp_ratio.min() >= act.kp_scale[0] - 1e-6 and kp_ratio.max() <= act.kp_scale[1] + 1e-6
    assert kd_ratio.min() >= act.kd_scale[0] - 1e-6 and kd_ratio.max() <= act.kd_scale[1] + 1e-6
    assert kp_ratio.min() < act.kp_scale[0] + 0.01 and kp_ratio.max() > act.kp_scale[1] - 0.01
    off = info["encoder_offset"]
    assert np.abs(off).max() <= act.encoder_offset + 1e-7 and np.abs(off).max() > 0.9 * act.encoder_offset
    dq0 = qpos - env.default_pose
    assert np.abs(dq0).max() <= env.config.init_noise + 1e-6
    np.testing.assert_array_equal(qvel, 0.0)
    assert batches[0].info["act_buf"].shape == (BATCH, 3, 14)
