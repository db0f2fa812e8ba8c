"""The PPO networks: brax's tanh-normal policy and value MLPs at this project's sizes, with an action prior.

``make_networks`` builds brax's ``PPONetworks`` (``brax.training.agents.ppo.networks``) from a
``NetworkConfig`` (layer sizes, activation) and, for a task with an action prior (``obs.action_prior``),
adds the prior's pre-tanh action to the policy's mean so that a zero MLP output is the prior's action. The
learner (``training.brax.learner``), the exporter and the rsl-rl backend's actor start (``rsl_rl.prior``)
share it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.training import networks as brax_networks
from brax.training import types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen

from bar_policy.obs.action_prior import Prior, check_fits
from bar_policy.training.config import NetworkConfig

__all__ = ["BRAX_MIN_STD", "PRIOR_INIT_SCALE", "make_networks"]

_ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "swish": linen.swish,
    "elu": linen.elu,
    "relu": linen.relu,
    "tanh": linen.tanh,
}


PRIOR_INIT_SCALE = 0.01
"""With an action prior, the initial loc kernel of the policy's output layer is brax's times this (its bias
0): CleanRL's and Stable-Baselines3's policy-head gain of 0.01, so training starts from the prior."""


BRAX_MIN_STD = 0.001
"""brax's ``NormalTanhDistribution`` minimum std: its scale is ``softplus(raw) + BRAX_MIN_STD``."""


def make_networks(
    observation_size: int,
    action_size: int,
    net: NetworkConfig,
    normalize: bool,
    prior: Prior | None = None,
) -> ppo_networks.PPONetworks:
    """Brax PPO networks (tanh-normal policy) with our layer sizes and activation.

    With ``prior``, the policy's pre-tanh mean is the MLP's plus ``prior.pre_tanh(obs)`` of the raw
    (unnormalised) observation, so a zero MLP output is the prior's action; the scale half is untouched.
    """
    networks = _brax_networks(observation_size, action_size, net, normalize)
    if prior is None:
        return networks
    check_fits(prior, observation_size, action_size)
    base = networks.policy_network

    def init(key: jax.Array) -> Any:
        # The loc half of the output layer starts at PRIOR_INIT_SCALE of brax's init, so the first policy
        # is the prior plus a small perturbation rather than the prior drowned in a random MLP's output.
        params = base.init(key)
        layers = params["params"]
        last = max(layers, key=lambda s: int(s.rsplit("_", 1)[1]))
        kernel, bias = layers[last]["kernel"], layers[last]["bias"]
        kernel = kernel.at[:, :action_size].multiply(PRIOR_INIT_SCALE)
        bias = bias.at[:action_size].set(0.0)
        if net.prior_noise_std is not None:
            # brax's tanh-normal std is softplus(raw) + 0.001: a near-zero kernel and this bias start every
            # action's std at prior_noise_std, rather than softplus(0) = 0.69, which hides the prior's pose.
            kernel = kernel.at[:, action_size:].multiply(PRIOR_INIT_SCALE)
            bias = bias.at[action_size:].set(math.log(math.expm1(net.prior_noise_std - BRAX_MIN_STD)))
        return {**params, "params": {**layers, last: {**layers[last], "kernel": kernel, "bias": bias}}}

    def apply(processor_params: Any, policy_params: Any, obs: jax.Array) -> jax.Array:
        loc, scale = jnp.split(base.apply(processor_params, policy_params, obs), 2, axis=-1)
        return jnp.concatenate([loc + prior.pre_tanh(obs), scale], axis=-1)

    policy = brax_networks.FeedForwardNetwork(init=init, apply=apply)
    return dataclasses.replace(networks, policy_network=policy)


def _brax_networks(
    observation_size: int, action_size: int, net: NetworkConfig, normalize: bool
) -> ppo_networks.PPONetworks:
    return ppo_networks.make_ppo_networks(
        observation_size,
        action_size,
        preprocess_observations_fn=running_statistics.normalize
        if normalize
        else types.identity_observation_preprocessor,
        policy_hidden_layer_sizes=net.policy_hidden,
        value_hidden_layer_sizes=net.value_hidden,
        activation=_ACTIVATIONS[net.activation],
    )
