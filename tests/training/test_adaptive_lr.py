"""The KL-adaptive learning rate of the brax backend: the rule, the optimizer state, the KL estimate."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.training import types
from brax.training.acme import running_statistics, specs
from kl_reference import approx_kl

from bar_policy.training.brax.learner import (
    adapt_learning_rate,
    learning_rate,
    make_learner,
    set_learning_rate,
)
from bar_policy.training.config import NetworkConfig, PPOConfig

PPO = PPOConfig(
    schedule="adaptive", desired_kl=0.01, learning_rate=1e-3, min_learning_rate=1e-4, max_learning_rate=2e-3
)


@pytest.mark.parametrize(
    ("lr", "kl", "want"),
    [
        (1e-3, 0.03, 1e-3 / 1.5),  # KL 3x the target (> 2x): slow down
        (1e-3, 0.004, 1.5e-3),  # below half the target: speed up
        (1e-3, 0.01, 1e-3),  # inside [target / 2, 2 target]: keep
        (1.8e-3, 0.001, 2e-3),  # 2.7e-3 clipped to the ceiling
        (1.2e-4, 0.5, 1e-4),  # 8e-5 clipped to the floor
    ],
)
def test_rule_by_hand(lr, kl, want):
    assert float(adapt_learning_rate(jnp.float32(lr), jnp.float32(kl), PPO)) == pytest.approx(want, rel=1e-6)


def test_learning_rate_lives_in_the_optimizer_state_and_drives_adam():
    learner = make_learner(4, 2, PPO, NetworkConfig(policy_hidden=(8,), value_hidden=(8,)))
    params = {"w": jnp.array([1.0, -2.0])}
    state = learner.optimizer.init(params)
    assert float(learning_rate(state)) == pytest.approx(1e-3)
    state = set_learning_rate(state, 5e-4)
    assert float(learning_rate(state)) == pytest.approx(5e-4)
    # Adam's first step is -lr * g / (|g| + eps) per entry (bias-corrected moments m = g, v = g^2), after
    # clipping the global norm to ppo.max_grad_norm = 1: g = [3, 4] / 5.
    updates, _ = learner.optimizer.update({"w": jnp.array([3.0, 4.0])}, state, params)
    np.testing.assert_allclose(updates["w"], [-5e-4, -5e-4], rtol=1e-5)


def test_kl_estimate_is_zero_on_policy_and_matches_the_gaussian_kl():
    n_obs, n_act, batch = 6, 3, 20_000
    learner = make_learner(n_obs, n_act, PPO, NetworkConfig(policy_hidden=(16,), value_hidden=(16,)))
    nets = learner.networks
    k_old, k_new, k_obs, k_act = jax.random.split(jax.random.PRNGKey(0), 4)
    norm = running_statistics.init_state(specs.Array((n_obs,), jnp.float32))
    old = nets.policy_network.init(k_old)
    obs = jax.random.normal(k_obs, (1, n_obs)).repeat(batch, axis=0)  # one state, many action samples
    dist = nets.parametric_action_distribution
    logits = nets.policy_network.apply(norm, old, obs)
    raw = dist.sample_no_postprocessing(logits, k_act)
    data = types.Transition(
        observation=obs,
        action=raw,
        reward=None,
        discount=None,
        next_observation=None,
        extras={"policy_extras": {"raw_action": raw, "log_prob": dist.log_prob(logits, raw)}},
    )
    ppo_params = dataclasses.make_dataclass("P", ["policy"])
    assert float(approx_kl(learner, ppo_params(old), norm, data)) == pytest.approx(0.0, abs=1e-7)
    # Another policy: the estimate of KL(old || new) converges to the Gaussians' KL (the tanh's Jacobian
    # cancels in the ratio). Per action dimension KL = log(s1/s0) + (s0^2 + (m0 - m1)^2) / (2 s1^2) - 1/2.
    new = jax.tree.map(lambda a, b: 0.8 * a + 0.2 * b, old, nets.policy_network.init(k_new))
    d0, d1 = dist.create_dist(logits[:1]), dist.create_dist(nets.policy_network.apply(norm, new, obs[:1]))
    m0, s0, m1, s1 = (np.asarray(x, np.float64)[0] for x in (d0.loc, d0.scale, d1.loc, d1.scale))
    exact = float(np.sum(np.log(s1 / s0) + (s0**2 + (m0 - m1) ** 2) / (2 * s1**2) - 0.5))
    est = float(approx_kl(learner, ppo_params(new), norm, data))
    # The estimate is of the joint KL (sum over action dimensions, as rsl-rl's). Monte Carlo error: the
    # per-sample values' std / sqrt(20000), about 1 % of the mean here; 5 % allowed.
    assert exact > 1e-3
    assert est == pytest.approx(exact, rel=0.05)
