"""The critic warm-up (``ppo.actor_warmup_iterations``): the policy is frozen exactly, the critic learns."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types

from bar_policy.training.brax.learner import adam_count, make_learner
from bar_policy.training.config import NetworkConfig, PPOConfig
from bar_policy.training.parallel import AXIS

N_OBS, N_ACT, SEGMENTS, T = 6, 3, 8, 5


def _learner(warmup: int):
    # 2 minibatches x 2 passes = 4 Adam steps per iteration.
    ppo = PPOConfig(
        num_envs=4,
        batch_size=4,
        num_minibatches=2,
        unroll_length=T,
        num_updates_per_batch=2,
        actor_warmup_iterations=warmup,
    )
    return make_learner(N_OBS, N_ACT, ppo, NetworkConfig(policy_hidden=(8,), value_hidden=(8,)))


def _data(learner, ts, key) -> types.Transition:
    """On-policy transitions of the initial policy on random observations, shape (SEGMENTS, T, ...)."""
    k_obs, k_act, k_rew = jax.random.split(key, 3)
    obs = jax.random.normal(k_obs, (SEGMENTS, T + 1, N_OBS))
    policy = learner.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))
    flat = obs[:, :T].reshape(-1, N_OBS)
    action, extras = policy(flat, k_act)
    unflat = lambda x: x.reshape(SEGMENTS, T, *x.shape[1:])  # noqa: E731
    return types.Transition(
        observation=obs[:, :T],
        action=unflat(action),
        reward=jax.random.normal(k_rew, (SEGMENTS, T)),
        discount=jnp.ones((SEGMENTS, T)),
        next_observation=obs[:, 1:],
        extras={
            "policy_extras": jax.tree.map(unflat, extras),
            "state_extras": {"truncation": jnp.zeros((SEGMENTS, T))},
        },
    )


def _updates(warmup: int, iterations: int):
    learner = _learner(warmup)
    ts0 = learner.init(jax.random.PRNGKey(0))
    data = _data(learner, ts0, jax.random.PRNGKey(1))

    def run(_: jax.Array):  # pmean needs the data-parallel axis: one device's worth under vmap
        ts, out = ts0, []
        for i in range(iterations):
            ts, _ = learner.update(ts, data, jax.random.PRNGKey(10 + i))
            out.append(ts)
        return out

    states = jax.tree.map(lambda x: x[0], jax.vmap(run, axis_name=AXIS)(jnp.zeros(1)))
    return ts0, states


def _changed(a, b) -> bool:
    return any(not np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


@pytest.mark.slow
def test_warmup_freezes_the_policy_exactly_and_trains_the_critic():
    ts0, (after1, after2) = _updates(warmup=1, iterations=2)
    assert int(adam_count(after1.optimizer_state)) == 4 and int(adam_count(after2.optimizer_state)) == 8
    # Iteration 1 = Adam steps 0..3 < 1 x 2 x 2: the policy's gradients are zero, so its update is 0 exactly.
    assert not _changed(ts0.params.policy, after1.params.policy)
    assert _changed(ts0.params.value, after1.params.value)
    # Iteration 2 (steps 4..7): released.
    assert _changed(after1.params.policy, after2.params.policy)


def test_without_warmup_the_policy_moves_in_the_first_iteration():
    ts0, (after1,) = _updates(warmup=0, iterations=1)
    assert _changed(ts0.params.policy, after1.params.policy)


def test_negative_warmup_is_refused():
    with pytest.raises(ValueError, match=r"ppo.actor_warmup_iterations must be >= 0, got -1"):
        PPOConfig(actor_warmup_iterations=-1)
