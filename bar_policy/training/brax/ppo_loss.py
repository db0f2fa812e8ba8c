"""brax's PPO loss, written for few GPU kernels per SGD step (the learner's; ``learner.Learner``).

The same quantities as ``brax.training.agents.ppo.losses.compute_ppo_loss`` with a plain critic and no
value clipping (the configuration the learner uses): GAE from the current critic on every minibatch, the
clipped probability ratio, the value loss, the entropy bonus of brax's tanh-normal (with its sampled Jacobian
term). A test holds the loss and its gradients equal to brax's (``tests/training/test_ppo_loss.py``).

With targets in ``data.extras["value_targets"]`` (``with_value_targets``: GAE taken once per SGD pass or per
iteration, ``PPOConfig.value_targets``) the loss uses them instead of recomputing GAE, and runs the critic on
the steps only: brax's loss at the parameters the targets were taken at, fixed targets after.

What differs is the program, not the numbers. On one H100 the update runs about 160 kernels per Adam step
of a few microseconds each (docs/performance.md, 2026-11-27), so its time is their count:

- **GAE unrolled at trace time.** brax runs the backward recursion as a ``lax.scan``: a ``unroll_length``
  (10) iteration loop on every minibatch. Unrolled, it is element-wise work over the batch that XLA fuses
  into a few kernels.
- **One critic pass.** The bootstrap value (the critic at the last step's next observation) goes through
  the critic with the segment's observations, as a ``unroll_length + 1``-th row, not as a second call.
- **The KL from the loss's own policy pass.** The adaptive schedule's KL estimate (``kl_estimate``, for
  rsl-rl's rule) needs the current policy's log-probabilities of the stored actions; the loss computes them
  anyway, so it returns the estimate as a metric instead of the learner running the policy a second time.
- **Fewer metrics.** The loss terms, the KL estimate and the policy's mean std (brax's six other
  distribution statistics and its second KL are left out: each is a reduction kernel per Adam step).

Shapes: ``data`` is batch-major, leaves ``[B, T, ...]`` (the learner's minibatch), as brax's.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.training import types
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks

__all__ = ["gae", "kl_estimate", "ppo_loss", "with_value_targets"]


def gae(
    truncation: jax.Array,
    termination: jax.Array,
    rewards: jax.Array,
    values: jax.Array,
    bootstrap_value: jax.Array,
    lambda_: float,
    discount: float,
) -> tuple[jax.Array, jax.Array]:
    """Value targets ``vs`` and advantages, both ``[T, B]``, as brax's ``compute_gae``.

    Args:
        truncation: ``[T, B]`` 0/1, the step ended its episode by the time limit (it keeps no TD error).
        termination: ``[T, B]`` 0/1, the step ended its episode for good (no bootstrap past it).
        rewards: ``[T, B]``.
        values: ``[T, B]``, the critic at each step.
        bootstrap_value: ``[B]``, the critic at step ``T``.
        lambda_: GAE's lambda.
        discount: the per-step discount.

    The recursion ``acc_t = delta_t + discount * lambda_ * (1 - term_t) * (1 - trunc_t) * acc_{t+1}`` runs
    over ``T`` in Python (trace time): ``T`` is a static shape, 10 in the presets.
    """
    live = 1.0 - truncation
    cont = discount * (1.0 - termination)
    values_next = jnp.concatenate([values[1:], bootstrap_value[None]], axis=0)
    deltas = (rewards + cont * values_next - values) * live
    carry = cont * live * lambda_
    acc = jnp.zeros_like(bootstrap_value)
    rows = []
    for t in range(values.shape[0] - 1, -1, -1):
        acc = deltas[t] + carry[t] * acc
        rows.append(acc)
    vs = jnp.stack(rows[::-1]) + values
    vs_next = jnp.concatenate([vs[1:], bootstrap_value[None]], axis=0)
    advantages = (rewards + cont * vs_next - values) * live
    return jax.lax.stop_gradient(vs), jax.lax.stop_gradient(advantages)


def _targets(
    params: ppo_losses.PPONetworkParams,
    normalizer_params: Any,
    data: types.Transition,
    ppo_network: ppo_networks.PPONetworks,
    discounting: float,
    reward_scaling: float,
    gae_lambda: float,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(vs, advantages, baseline)``, each ``[T, B]``, of time-major ``data`` under ``params``' critic."""
    # The critic at [obs_0 .. obs_{T-1}, next_obs_{T-1}]: the baseline and the bootstrap in one pass.
    obs = jax.tree.map(lambda o, n: jnp.concatenate([o, n[-1:]]), data.observation, data.next_observation)
    values_all = ppo_network.value_network.apply(normalizer_params, params.value, obs)
    baseline, bootstrap_value = values_all[:-1], values_all[-1]
    truncation = data.extras["state_extras"]["truncation"]
    termination = (1 - data.discount) * (1 - truncation)
    vs, advantages = gae(
        truncation=truncation,
        termination=termination,
        rewards=data.reward * reward_scaling,
        values=baseline,
        bootstrap_value=bootstrap_value,
        lambda_=gae_lambda,
        discount=discounting,
    )
    return vs, advantages, baseline


def with_value_targets(
    params: ppo_losses.PPONetworkParams,
    normalizer_params: Any,
    data: types.Transition,
    ppo_network: ppo_networks.PPONetworks,
    discounting: float,
    reward_scaling: float,
    gae_lambda: float,
) -> types.Transition:
    """``data`` with GAE's targets and advantages under ``params``' critic in ``extras["value_targets"]``.

    ``{"vs", "advantages"}``, both ``[B, T]``, for batch-major ``data`` (leaves ``[B, T, ...]``). Given them
    before an SGD pass (or before all of them, as rsl-rl, Stable-Baselines3 and CleanRL do), ``ppo_loss``
    regresses the critic on these fixed targets and weighs the policy by these advantages (normalised per
    minibatch), instead of recomputing both from the critic being trained at every minibatch as brax does
    (``PPOConfig.value_targets``).
    """
    tm = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), data)
    vs, advantages, _ = _targets(
        params, normalizer_params, tm, ppo_network, discounting, reward_scaling, gae_lambda
    )
    targets = {"vs": jnp.swapaxes(vs, 0, 1), "advantages": jnp.swapaxes(advantages, 0, 1)}
    return data._replace(extras={**data.extras, "value_targets": targets})


def kl_estimate(log_prob_new: jax.Array, log_prob_old: jax.Array) -> jax.Array:
    """KL(behaviour || current) estimated as ``mean(r - 1 - log r)``, ``r`` the probability ratio, nats.

    Its expectation under the behaviour policy is the KL divergence of the joint action distribution (the
    tanh's Jacobian cancels in the ratio of the stored raw actions), as rsl-rl measures it for its schedule.
    """
    log_r = log_prob_new - log_prob_old
    return jnp.mean(jnp.exp(log_r) - 1.0 - log_r)


def ppo_loss(
    params: ppo_losses.PPONetworkParams,
    normalizer_params: Any,
    data: types.Transition,
    rng: jax.Array,
    ppo_network: ppo_networks.PPONetworks,
    entropy_cost: float,
    discounting: float,
    reward_scaling: float,
    gae_lambda: float,
    clipping_epsilon: float,
    normalize_advantage: bool,
    vf_coefficient: float,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The loss of brax's ``compute_ppo_loss`` (same arguments, plain critic) -> ``(loss, metrics)``.

    ``metrics``: ``total_loss``, ``policy_loss``, ``v_loss``, ``entropy_loss``, ``kl`` (``kl_estimate`` of
    the parameters the loss is taken at) and ``policy_dist_mean_std``.
    """
    dist = ppo_network.parametric_action_distribution
    data = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), data)  # time first: [T, B, ...]
    logits = ppo_network.policy_network.apply(normalizer_params, params.policy, data.observation)
    fixed = data.extras.get("value_targets")
    if fixed is not None:  # taken before the pass (``with_value_targets``): the critic on the steps only
        baseline = ppo_network.value_network.apply(normalizer_params, params.value, data.observation)
        vs, advantages = fixed["vs"], fixed["advantages"]
    else:
        vs, advantages, baseline = _targets(
            params, normalizer_params, data, ppo_network, discounting, reward_scaling, gae_lambda
        )
    if normalize_advantage:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)

    extras = data.extras["policy_extras"]
    log_prob = dist.log_prob(logits, extras["raw_action"])
    rho = jnp.exp(log_prob - extras["log_prob"])
    clipped = jnp.clip(rho, 1 - clipping_epsilon, 1 + clipping_epsilon)
    policy_loss = -jnp.mean(jnp.minimum(rho * advantages, clipped * advantages))
    v_error = vs - baseline
    v_loss = jnp.mean(v_error * v_error) * 0.5 * vf_coefficient
    entropy_loss = entropy_cost * -jnp.mean(dist.entropy(logits, rng))
    total = policy_loss + v_loss + entropy_loss
    return total, {
        "total_loss": total,
        "policy_loss": policy_loss,
        "v_loss": v_loss,
        "entropy_loss": entropy_loss,
        "kl": jax.lax.stop_gradient(kl_estimate(log_prob, extras["log_prob"])),
        "policy_dist_mean_std": jnp.mean(dist.create_dist(logits).scale),
    }
