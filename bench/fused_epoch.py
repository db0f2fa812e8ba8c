"""The epoch as one program (a scan of PPO iterations), as ``training.brax.programs`` once built it.

For the benches that compare it with the trainer's two programs (``rollout``, ``update``): same keys per
iteration, same totals (mean losses, summed stats), one compile.
"""

from __future__ import annotations

from typing import Any

import jax
from jax.sharding import PartitionSpec as P

from bar_policy.training.brax.learner import Learner, strip_weak_type
from bar_policy.training.brax.programs import slot_env
from bar_policy.training.parallel import AXIS, DataParallel


def fused_epoch(
    env: Any, cfg: Any, learner: Learner, dp: DataParallel, wrap: Any, randomizer: Any, iters: int
) -> Any:
    """``epoch(ts, envs, key) -> ts, envs, losses, sums``: ``iters`` iterations in one ``lax.scan``."""
    ppo = cfg.ppo
    unrolls = ppo.batch_size * ppo.num_minibatches // ppo.num_envs

    def epoch(ts: Any, envs: tuple[Any, jax.Array], key: jax.Array) -> tuple:
        env_state, model_keys = envs
        env_b = slot_env(env, wrap, randomizer, model_keys)
        key = jax.random.fold_in(key, jax.lax.axis_index(AXIS))

        def body(c: tuple, _: None) -> tuple:
            ts, s, k = c
            k, k_it = jax.random.split(k)
            ts, s, metrics, stats = learner.iteration(ts, s, k_it, env_b, unrolls)
            return (ts, s, k), (metrics, stats)

        (ts, env_state, _), (metrics, stats) = jax.lax.scan(body, (ts, env_state, key), None, length=iters)
        metrics = jax.lax.pmean(jax.tree.map(lambda x: x.mean(), metrics), axis_name=AXIS)
        stats = jax.lax.psum(stats.sum(axis=0), axis_name=AXIS)
        return strip_weak_type(ts), (env_state, model_keys), metrics, stats

    rep, shard = P(), P(AXIS)
    return dp.sharded_jit(epoch, (rep, shard, rep), (rep, shard, rep, rep), donate_argnums=(0, 1))
