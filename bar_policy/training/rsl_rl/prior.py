"""The action prior (``obs.action_prior``) on the rsl-rl backend: the env adds it, PPO never sees it.

rsl-rl's actor is a Gaussian over unsquashed actions whose deterministic output is the MLP's mean, and the
env clips whatever it is given to [-1, 1] (``LiteRobotEnv.filtered_action``; the deploy runtime applies the
same clip, ``bar.action_clip`` = 1). With ``network.action_prior`` the actor's sample ``r`` is a residual
and the env is commanded

    a = prior(obs) + r          (action units, shape (num_envs, A); the env then clips a to [-1, 1])

computed on the device in JAX inside the jitted step (``RslRlVecEnv.from_env(prior=...)``,
``commanded_action``) from the same raw observation the actor was given (``state.obs``, before the actor's
normaliser). The prior is a deterministic function of the observation, so ``r ~ N(mu(obs), sigma)`` is exactly
``a ~ N(prior(obs) + mu(obs), sigma)``: rsl-rl's log-probabilities, entropy and KL of the residual are those
of a Gaussian policy whose mean is shifted by the prior, and its PPO, runner, storage and distribution run
unchanged. The evaluations (inside training and the final one) step an env built with the same prior.

Why additive and not brax's ``tanh(mlp + atanh(prior))``: brax's head is tanh-normal, so it adds the prior
before its squash; rsl-rl's head has no squash (the env's clip bounds the action), so the prior is added in
action units, where a zero residual commands the prior itself. A tanh in the env would change rsl-rl's
action semantics (its noise would be in pre-tanh units) for no gain. The exported file is the same
``MlpPolicy`` with the ``identity`` head and ``prior`` (``bar_policy.export.graph``: Gather, Mul, Add, Clip,
then Add to the MLP output, no Atanh), so its output is the deterministic ``a`` the env was commanded
during training, before the same [-1, 1] clip (the runtime's).

As brax does (``training.brax.networks.PRIOR_INIT_SCALE``), a fresh actor's output layer starts at 0.01 of its
init with a zero bias (``start_actor_at_prior``), so the first policy's mean is within a few 1e-3 of the
prior; and ``network.prior_noise_std``, when set, is the initial action noise std
(``rsl_rl.config.rsl_rl_train_cfg``).

Torch-free at import (torch only inside ``start_actor_at_prior``): ``rsl_rl.programs`` builds the envs'
programs with ``commanded_action`` before torch is imported. The prior itself is the run's
``training.prior.action_prior``, as on the brax backend; ``rsl_rl.programs.EnvPrograms`` checks that it fits
the env it is added to.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax

from bar_policy.obs.action_prior import Prior
from bar_policy.training.brax.networks import PRIOR_INIT_SCALE

if TYPE_CHECKING:
    import torch

__all__ = ["commanded_action", "start_actor_at_prior"]


def commanded_action(prior: Prior | None, obs: jax.Array, residual: jax.Array) -> jax.Array:
    """The action the env is given: ``prior(obs) + residual``, or ``residual`` without a prior.

    Args:
        prior: the action prior, or None.
        obs: raw observations the actor saw, shape (num_envs, obs).
        residual: the actor's actions, shape (num_envs, A), action units.

    Returns:
        Shape (num_envs, A), unclipped (the env clips to [-1, 1], as the deploy runtime does).
    """
    if prior is None:
        return residual
    return residual + prior.apply(obs)


def start_actor_at_prior(actor: torch.nn.Module, scale: float = PRIOR_INIT_SCALE) -> None:
    """Scale the last ``Linear`` of ``actor.mlp`` by ``scale`` and zero its bias, in place.

    With a prior, the first mean is then ``prior(obs)`` plus a few 1e-3 rather than the prior drowned in a
    random MLP's output (brax's ``make_networks`` does the same to its loc half).
    """
    import torch  # here, not at the top: ``commanded_action`` serves torch-free code

    last = [m for m in actor.mlp if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.mul_(scale)
        last.bias.zero_()
