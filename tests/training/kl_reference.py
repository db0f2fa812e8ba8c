"""The KL estimate taken the long way, for tests: the policy run again on a minibatch, then ``kl_estimate``.

The learner takes the KL from the loss's own policy pass (``training.brax.ppo_loss``); this separate pass is
what the tests hold that metric and the estimator to (a module of its own: importable by a name no other test
folder uses).
"""

from __future__ import annotations

from typing import Any

import jax

from bar_policy.training.brax.learner import Learner
from bar_policy.training.brax.ppo_loss import kl_estimate


def approx_kl(learner: Learner, params: Any, normalizer: Any, mb: Any) -> jax.Array:
    """KL(behaviour policy || the policy of ``params``) on the minibatch ``mb``, nats.

    The joint (all action dimensions) KL averaged over the minibatch's states, as rsl-rl measures it:
    ``kl_estimate`` of the stored raw (pre-tanh) actions' log-probabilities (the tanh's Jacobian cancels in
    the ratio).
    """
    logits = learner.networks.policy_network.apply(normalizer, params.policy, mb.observation)
    extras = mb.extras["policy_extras"]
    new = learner.networks.parametric_action_distribution.log_prob(logits, extras["raw_action"])
    return kl_estimate(new, extras["log_prob"])
