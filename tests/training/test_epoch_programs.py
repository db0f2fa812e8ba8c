"""The epoch as two programs (``rollout``, ``update``: ``brax.state.run_epoch``) against one ``lax.scan``.

Until 2026-11-27 the trainer compiled an epoch as one program, a scan of ``Learner.iteration`` whose keys
came from one chain (``k, k_it = split(k)`` per iteration after folding in the device index). Since then
the rollout and the update are programs of their own, which each derive iteration ``i``'s key from the
chain. The reference here is that scan, written out again; both start from the same state and must reach
the same state, losses and sums on the stand-in env.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P
from toy_configs import TOY_BRAX, toy_config

from bar_policy import envs
from bar_policy.envs.reward_weights import weights
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.programs import make_programs, slot_env
from bar_policy.training.brax.state import epoch_totals, host_key, run_epoch
from bar_policy.training.parallel import AXIS, DataParallel

ITERS = 3


def _fused_epoch(env, cfg, learner, dp):
    """The pre-session-34 epoch program: ``ITERS`` iterations in one scan, totals reduced in the program."""
    ppo = cfg.ppo
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs

    def epoch(ts, env_carry, key):
        env_state, model_keys = env_carry
        env_b = slot_env(env, envs.wrap_for_brax_training, None, model_keys)
        key = jax.random.fold_in(key, jax.lax.axis_index(AXIS))

        def body(c, _):
            ts, s, k = c
            k, k_it = jax.random.split(k)
            ts, s, metrics, stats = learner.iteration(ts, s, k_it, env_b, unrolls)
            return (ts, s, k), (metrics, stats)

        (ts, env_state, _), (metrics, stats) = jax.lax.scan(body, (ts, env_state, key), None, length=ITERS)
        metrics = jax.lax.pmean(jax.tree.map(lambda x: x.mean(), metrics), axis_name=AXIS)
        return ts, env_state, metrics, jax.lax.psum(stats.sum(axis=0), axis_name=AXIS)

    return dp.sharded_jit(epoch, (P(), P(AXIS), P()), (P(), P(AXIS), P(), P()))


@pytest.fixture(scope="module")
def both_epochs(tmp_path_factory, toy_env):
    cfg = toy_config(tmp_path_factory.mktemp("runs"), "split", TOY_BRAX)
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(toy_env.observation_size, toy_env.action_size, cfg.ppo, cfg.network)
    progs = make_programs(toy_env, cfg, learner, dp, envs.wrap_for_brax_training, None)
    key = dp.replicate(host_key(0, 7))

    def start():
        ts = progs.init(dp.replicate(host_key(0, 1)))
        return ts, progs.reset(dp.replicate(host_key(0, 2)), dp.replicate(host_key(0, 3)))

    ts, env_carry = start()
    index = [dp.replicate(np.int32(i)) for i in range(ITERS)]
    w = dp.replicate(weights(toy_env))  # the toy env has no reward weights: an empty argument
    ts_s, carry_s, metrics, stats = run_epoch(progs.rollout, progs.update, ts, env_carry, key, index, w)
    split = (dp.to_host(ts_s), dp.to_host(carry_s[0].obs), *epoch_totals(*dp.to_host((metrics, stats))))
    ts, env_carry = start()
    ts_f, state_f, metrics_f, stats_f = _fused_epoch(toy_env, cfg, learner, dp)(ts, env_carry, key)
    fused = (dp.to_host(ts_f), dp.to_host(state_f.obs), dp.to_host(metrics_f), dp.to_host(stats_f))
    return split, fused


def test_two_programs_reach_the_scan_s_state(both_epochs):
    """Same keys, same arithmetic: the params, Adam moments, normaliser and env observations after three
    iterations agree to float32 rounding. XLA fuses the scan body and the two programs apart, so their
    sums may round in another order: 1e-6 relative (a few float32 ulps, 2**-23 = 1.2e-7, over 3 iterations of
    16 Adam steps) plus 1e-6 absolute for values near 0."""
    (ts_s, obs_s, _, _), (ts_f, obs_f, _, _) = both_epochs
    leaves_s, leaves_f = jax.tree.leaves(ts_s), jax.tree.leaves(ts_f)
    assert len(leaves_s) == len(leaves_f) > 0
    for a, b in zip(leaves_s, leaves_f, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(obs_s, obs_f, rtol=1e-6, atol=1e-6)


def test_two_programs_total_the_losses_and_stats_alike(both_epochs):
    """Losses: the scan's mean over its iterations = the mean of the per-iteration means (equal counts);
    stats: its sum over iterations = the host's sum. Same float32 tolerance as above."""
    (_, _, metrics_s, stats_s), (_, _, metrics_f, stats_f) = both_epochs
    assert set(metrics_s) == set(metrics_f)
    for k in metrics_f:
        np.testing.assert_allclose(metrics_s[k], metrics_f[k], rtol=1e-6, atol=1e-6, err_msg=k)
    np.testing.assert_allclose(stats_s, stats_f, rtol=1e-6)
    assert stats_s[2] > 0  # episodes ended within the three iterations: the sums are not all empty
