"""The learner's parts (``brax.learner``): the rollout's layout and the update's matmul precision.

``ppo.update_precision`` sets the precision of the update's matrix products and of no other.
"""

from __future__ import annotations

import jax
import jax.extend.core as jex
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types
from toy_configs import TOY_BRAX, toy_config

from bar_policy.training.brax.learner import make_learner, segments
from bar_policy.training.parallel import AXIS


def test_segments_put_each_env_s_steps_in_one_row():
    """(unrolls, T, envs) -> (unrolls * envs, T): row u * envs + e holds unroll u of env e, in step order."""
    unrolls, steps, n = 2, 3, 4
    x = np.arange(unrolls * steps * n).reshape(unrolls, steps, n)  # value = (u * T + t) * envs + e
    out = np.asarray(segments({"x": jnp.asarray(x)})["x"])
    assert out.shape == (unrolls * n, steps)
    for u in range(unrolls):
        for e in range(n):
            assert out[u * n + e].tolist() == [(u * steps + t) * n + e for t in range(steps)]


def _dot_precisions(jaxpr: jex.Jaxpr) -> list[str]:
    """Each ``dot_general``'s precision in ``jaxpr``, in program order (sub-jaxprs in place)."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            precision = eqn.params["precision"]  # (lhs, rhs) Precisions, or a DotAlgorithmPreset
            found.append(precision[0].name if isinstance(precision, tuple) else precision.name)
        for sub in jex.jaxprs_in_params(eqn.params):
            found += _dot_precisions(sub)
    return found


@pytest.mark.parametrize(
    "setting,printed",
    [
        ("run", "HIGHEST"),
        ("tensorfloat32", "HIGH"),
        ("BF16_BF16_F32_X3", "BF16_BF16_F32_X3"),
    ],
)
def test_update_precision_sets_the_sgd_passes_products_only(tmp_path, toy_env, setting, printed):
    """``ppo.update_precision`` reaches every product of the update (the pass's value targets, the loss and
    its gradient) and none of the policy's in the same program: a rollout keeps the run's full float32."""
    cfg = toy_config(tmp_path, setting, [*TOY_BRAX, f"ppo.update_precision={setting}"])
    ppo = cfg.ppo
    learner = make_learner(toy_env.observation_size, toy_env.action_size, ppo, cfg.network)
    ts = jax.jit(learner.init)(jax.random.PRNGKey(0))
    rows, obs, act = ppo.batch_size * ppo.num_minibatches, toy_env.observation_size, toy_env.action_size
    z = lambda *s: jnp.zeros((rows, ppo.unroll_length, *s))  # noqa: E731
    data = types.Transition(
        observation=z(obs),
        action=z(act),
        reward=z(),
        discount=z(),
        next_observation=z(obs),
        extras={
            "policy_extras": {"log_prob": z(), "raw_action": z(act)},
            "state_extras": {"truncation": z()},
        },
    )

    def both(ts, data, key):  # the policy before and after the update, as a trainer's programs run them
        policy = learner.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))
        first = policy(data.observation[:, 0], key)[0]
        new_ts, _ = learner.update(ts, data, key)
        return first, new_ts, policy(data.observation[:, 1], key)[0]

    key = jax.random.PRNGKey(1)
    with jax.default_matmul_precision("highest"):  # the run's (TrainConfig.matmul_precision = highest)
        found = _dot_precisions(jax.make_jaxpr(both, axis_env=[(AXIS, 1)])(ts, data, key).jaxpr)
    layers = len(cfg.network.policy_hidden) + 1  # one product per policy layer
    assert found[:layers] == found[-layers:] == ["HIGHEST"] * layers
    update = found[layers:-layers]
    # The pass's targets (critic forward) and the loss's forward and backward passes: at least one product
    # per layer of each network, each at the setting.
    assert len(update) >= layers + len(cfg.network.value_hidden) + 1
    assert update == [printed] * len(update)
