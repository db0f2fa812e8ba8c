"""The training programs take the reward weights as an argument (``envs.reward_weights``).

A run that changes only a weight must load the programs it compiled before. So the brax rollout and
evaluation, and the rsl-rl step, must lower to the same module whatever the weights' values (the
executable key leaves the values out: ``test_executable_cache``). And the argument must be what the
step weights its terms by: doubling every weight doubles the summed reward exactly (a binary float times
2 is exact, and so is a sum of doubled values), and leaves the physics alone.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.sharding import Mesh

from bar_policy import envs
from bar_policy.envs.reward_weights import weights
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.programs import _policy_params, make_programs
from bar_policy.training.config import apply_overrides, preset
from bar_policy.training.parallel import AXIS, DataParallel
from bar_policy.training.rsl_rl.programs import EnvPrograms

WEIGHT = "reward.scales.success=0.6"


@pytest.mark.slow
def test_brax_rollout_and_evaluation_lower_alike_for_any_weights():
    """Lowering only (a few seconds a program on a CPU), no compile."""
    cfg = apply_overrides(preset("tiny"), [])
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))

    def lowered(overrides: list[str]) -> tuple[str, str]:
        env = envs.load("LiteReach", overrides=overrides or None)
        learner = make_learner(env.observation_size, env.action_size, cfg.ppo, cfg.network)
        progs = make_programs(env, cfg, learner, dp, envs.wrap_for_brax_training, None)
        key = dp.abstract(np.zeros(2, np.uint32), sharded=False)
        ts = dp.abstract(jax.eval_shape(learner.init, key), sharded=False)
        w = dp.abstract(weights(env), sharded=False)
        env_abs = dp.abstract(progs.reset.trace(key, key).lower().out_info, sharded=True)
        i = dp.abstract(np.zeros((), np.int32), sharded=False)
        rollout = progs.rollout.trace(ts, env_abs, key, i, w).lower().as_text()
        evaluate = progs.evaluate.trace(_policy_params(ts), key, key, w).lower().as_text()
        return rollout, evaluate

    default = lowered([])
    changed = lowered([WEIGHT])
    assert changed[0] == default[0]
    assert changed[1] == default[1]


@pytest.mark.slow
def test_rsl_rl_step_weights_the_reward_by_its_argument():
    env = envs.load("LiteReach", config=envs.nominal_config())
    progs = EnvPrograms(env, 2, wrap_fn=envs.wrap_for_brax_training, seed=0)
    state, stats = progs.reset(progs.first_keys)
    actions = jnp.tile(0.4 * jnp.sin(jnp.arange(env.action_size, dtype=jnp.float32)), (2, 1))
    w = progs.weights
    ns, st = progs.step(state, actions, stats)  # on the env's own weights
    doubled = {k: 2 * v for k, v in w.items()}
    ns2, st2 = progs.step_jit(state, actions, stats, doubled)
    assert np.asarray(st2["reward"]) == 2 * np.asarray(st["reward"])
    np.testing.assert_array_equal(np.asarray(ns2.reward), 2 * np.asarray(ns.reward))
    np.testing.assert_array_equal(np.asarray(ns2.obs), np.asarray(ns.obs))  # the physics is the same
    assert progs.step_jit._cache_size() == 1  # one compiled step served both

    changed_env = envs.load("LiteReach", config=envs.nominal_config(), overrides=[WEIGHT])
    changed = EnvPrograms(changed_env, 2, wrap_fn=envs.wrap_for_brax_training)
    assert float(changed.weights["success"]) == np.float32(0.6)  # the run's own weights are its argument
    state_abs, stats_abs = jax.eval_shape(progs.reset_jit, progs.first_keys)
    a = jax.ShapeDtypeStruct(actions.shape, jnp.float32)
    w_abs = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype), w)
    assert (
        changed.step_jit.trace(state_abs, a, stats_abs, w_abs).lower().as_text()
        == progs.step_jit.trace(state_abs, a, stats_abs, w_abs).lower().as_text()
    )
