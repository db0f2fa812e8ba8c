"""What an evaluation counts, in both backends: one episode per slot, nothing after its first ``done``.

The stand-in env's episodes last 20 steps and its targets change every 10 (a segment end). Both evaluators
run 30 steps here: a slot's episode ends (time-out) at step 20, so its return is the sum of its first 20
rewards and it has 2 segment ends, not 3. The expected figures come from stepping the training wrapper
directly and summing the first 20 steps in numpy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import torch
from jax.sharding import PartitionSpec as P

from bar_policy.envs import wrap_for_brax_training
from bar_policy.envs.base import reach_eval_ratios
from bar_policy.training.brax import evaluation
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.programs import slot_env, slot_keys
from bar_policy.training.brax.state import host_key
from bar_policy.training.config import preset
from bar_policy.training.parallel import make_data_parallel
from bar_policy.training.rsl_rl.env import RslRlVecEnv

pytestmark = pytest.mark.slow

N, STEPS, EPISODE = 8, 30, 20


def _reference(env, keys, act):
    """Rewards, success ends and segment ends per step and slot, (STEPS, N), from the training wrapper."""
    batch = wrap_for_brax_training(env, episode_length=EPISODE)
    step = jax.jit(batch.step)
    state = jax.jit(batch.reset)(keys)
    rew, succ, seg = [], [], []
    for _ in range(STEPS):
        state = step(state, act(state.obs))
        rew.append(np.asarray(state.reward))
        succ.append(np.asarray(state.metrics["success_end"]))
        seg.append(np.asarray(state.metrics["segment_end"]))
    return np.array(rew), np.array(succ), np.array(seg)


def test_brax_evaluator_counts_one_episode_per_slot(toy_env):
    cfg = preset("tiny")
    learner = make_learner(toy_env.observation_size, toy_env.action_size, cfg.ppo, cfg.network)
    ts = jax.jit(learner.init)(jnp.asarray(host_key(0, 1)))
    params = (ts.normalizer_params, ts.params.policy)
    key = np.asarray(host_key(0, 2))
    dp = make_data_parallel()

    def evaluate(params, key):
        batch = slot_env(
            toy_env, wrap_for_brax_training, None, jnp.zeros((N, 2), jnp.uint32), auto_reset=False
        )
        state = batch.reset(slot_keys(key, N, N))
        return evaluation.evaluate(learner.make_policy, params, batch, state, key, STEPS)

    got = dp.sharded_jit(evaluate, (P(), P()), P())(dp.replicate(params), dp.replicate(key))
    policy = jax.jit(learner.make_policy(params, deterministic=True))
    rew, succ, seg = _reference(toy_env, jax.random.split(key, N), lambda obs: policy(obs, key)[0])
    ret = rew[:EPISODE].sum(axis=0)
    assert seg[:EPISODE].sum() == 2 * N and seg.sum() == 3 * N  # the third segment end is past the episode
    np.testing.assert_allclose(float(got["episode_reward"]), ret.mean(), rtol=1e-5)
    np.testing.assert_allclose(float(got["episode_reward_std"]), ret.std(), rtol=1e-4)
    np.testing.assert_allclose(float(got["success_rate"]), succ[:EPISODE].sum() / (2 * N), atol=1e-7)
    assert rew[EPISODE:].sum() > 0  # what the mask removed was not zero


def test_rsl_rl_vec_env_accumulates_on_device(toy_env):
    vec = RslRlVecEnv.from_env(toy_env, N, wrap_fn=wrap_for_brax_training, seed=0, device="cpu")
    vec.reset_all(seed=5)
    actions = torch.full((N, 14), 0.3)
    for _ in range(STEPS):
        vec.step(actions)
    stats = vec.take_stats()
    rew, succ, seg = _reference(
        toy_env, jax.random.split(jax.random.PRNGKey(5), N), lambda obs: jnp.full((N, 14), 0.3)
    )
    # Training sums: every step of every slot (the slot auto-resets at step 20 and goes on).
    np.testing.assert_allclose(stats["reward"], rew.sum(), rtol=1e-5)
    assert stats["success"] == (pytest.approx(float(succ.sum())), pytest.approx(float(seg.sum())))
    # Evaluation sums: the first episode only.
    np.testing.assert_allclose(stats["return"], rew[:EPISODE].sum(axis=0), rtol=1e-5)
    names = set(
        reach_eval_ratios(
            {k: jnp.zeros(()) for k in ("success_end", "segment_end", "dist_left", "dist_right")}
        )
    )
    assert set(stats["ratios"]) == names
    assert stats["ratios"]["success_rate"][1] == pytest.approx(2 * N)
    # Read once, then zeroed: the next read starts from nothing.
    again = vec.take_stats()
    assert again["reward"] == 0.0 and again["success"] == (0.0, 0.0)
