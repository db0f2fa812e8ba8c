"""brax's PPO as per-device functions: training state, one iteration (rollout, then update).

The networks are ``networks``'.

Everything here is written for one device's shard of the env batch and reduces across devices through the
mesh axis ``AXIS`` (``bar_policy.training.parallel``): ``lax.pmean`` of the gradients, brax's
``running_statistics.update(..., pmap_axis_name=AXIS)`` for the observation statistics, ``psum`` of the
logged sums. On one device the collectives are identities.

The algorithm is brax's (``brax.training.agents.ppo``): ``make_ppo_networks`` (tanh-normal policy),
``compute_ppo_loss`` (GAE, clipped ratio, entropy bonus; as ``training.brax.ppo_loss``, the same numbers in
fewer GPU kernels), running observation statistics, and its data layout
(``batch_size * num_minibatches`` segments of ``unroll_length`` steps per iteration, ``num_updates_per_batch``
shuffled passes of ``num_minibatches`` Adam steps).
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import flax
import jax
import jax.numpy as jnp
import optax
from brax.training import types
from brax.training.acme import running_statistics, specs
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks

from bar_policy.obs.action_prior import Prior
from bar_policy.training.brax.networks import make_networks
from bar_policy.training.brax.ppo_loss import ppo_loss, with_value_targets
from bar_policy.training.config import NetworkConfig, PPOConfig
from bar_policy.training.parallel import AXIS
from bar_policy.training.rollout_sums import step_sums, sum_layout

__all__ = [
    "Learner",
    "TrainingState",
    "adapt_learning_rate",
    "learning_rate",
    "make_learner",
    "segments",
    "set_learning_rate",
    "strip_weak_type",
]


@flax.struct.dataclass
class TrainingState:
    """Everything the learner carries between iterations (and what a checkpoint stores)."""

    optimizer_state: optax.OptState
    params: ppo_losses.PPONetworkParams
    normalizer_params: running_statistics.RunningStatisticsState


def segments(data: Any) -> Any:
    """A rollout's transitions by segment: ``(unrolls, T, envs, ...)`` -> ``(unrolls * envs, T, ...)``."""
    data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
    return jax.tree.map(lambda x: x.reshape((-1, *x.shape[2:])), data)


def strip_weak_type(tree: Any) -> Any:
    """Same tree without weak types, so a compiled program's outputs match its input types exactly."""
    return jax.tree.map(lambda x: jnp.asarray(x).astype(jnp.asarray(x).dtype), tree)


@dataclass(frozen=True)
class Learner:
    """brax PPO for one env's sizes and one config (see the module docstring)."""

    networks: ppo_networks.PPONetworks
    make_policy: Callable[..., Any]
    optimizer: optax.GradientTransformation
    ppo: PPOConfig
    observation_size: int

    def init(self, key: jax.Array) -> TrainingState:
        """Fresh params, Adam state and normaliser (jit it: eagerly it is dozens of tiny compiles)."""
        k_pol, k_val = jax.random.split(key)
        params = ppo_losses.PPONetworkParams(
            policy=self.networks.policy_network.init(k_pol), value=self.networks.value_network.init(k_val)
        )
        return strip_weak_type(
            TrainingState(
                optimizer_state=self.optimizer.init(params),
                params=params,
                normalizer_params=running_statistics.init_state(
                    specs.Array((self.observation_size,), jnp.float32), std_eps=self.ppo.obs_std_eps
                ),
            )
        )

    def _with_targets(self, params: Any, normalizer: Any, data: types.Transition) -> types.Transition:
        """``ppo_loss.with_value_targets`` under ``params``' critic with this config's GAE settings."""
        ppo = self.ppo
        return with_value_targets(
            params, normalizer, data, self.networks, ppo.discounting, ppo.reward_scaling, ppo.gae_lambda
        )

    def sgd_pass(self, carry: tuple, data: types.Transition, normalizer: Any) -> tuple:
        """One shuffled pass of ``num_minibatches`` Adam steps over this device's segments.

        ``carry`` = ``(optimizer state, params, key)``; returns ``(carry, metrics)``, ``update``'s scan body.
        Its matrix products are traced at ``ppo.update_precision`` (``run``: the surrounding precision).
        """
        precision = self.ppo.update_precision
        with contextlib.nullcontext() if precision == "run" else jax.default_matmul_precision(precision):
            return self._sgd_pass(carry, data, normalizer)

    def _sgd_pass(self, carry: tuple, data: types.Transition, normalizer: Any) -> tuple:
        """``sgd_pass`` under the precision it sets."""
        ppo = self.ppo
        opt_state, params, k = carry
        k, k_perm, k_mb = jax.random.split(k, 3)
        loss_fn = functools.partial(
            ppo_loss,
            ppo_network=self.networks,
            entropy_cost=ppo.entropy_cost,
            discounting=ppo.discounting,
            reward_scaling=ppo.reward_scaling,
            gae_lambda=ppo.gae_lambda,
            clipping_epsilon=ppo.clipping_epsilon,
            normalize_advantage=True,
            vf_coefficient=ppo.vf_loss_coefficient,
        )
        grad_fn = jax.value_and_grad(loss_fn, has_aux=True)
        warmup_steps = ppo.actor_warmup_iterations * ppo.num_updates_per_batch * ppo.num_minibatches

        if ppo.value_targets == "pass":  # fixed for this pass, from the critic it starts with
            data = self._with_targets(params, normalizer, data)
        # One permutation for every leaf: brax's per-leaf ``jax.random.permutation(k_perm, x)`` order.
        perm = jax.random.permutation(k_perm, jax.tree.leaves(data)[0].shape[0])

        def shuffle(x: jax.Array) -> jax.Array:
            return x[perm].reshape((ppo.num_minibatches, -1, *x.shape[1:]))

        def minibatch(c: tuple, mb: types.Transition) -> tuple:
            o, p, kk = c
            kk, k_loss = jax.random.split(kk)
            (_, metrics), grads = grad_fn(p, normalizer, mb, k_loss)
            # The KL of the parameters the gradient is taken at (from the loss's own policy pass).
            kl = jax.lax.pmean(metrics["kl"], axis_name=AXIS)
            if ppo.schedule == "adaptive":
                o = set_learning_rate(o, adapt_learning_rate(learning_rate(o), kl, ppo))
            grads = jax.lax.pmean(grads, axis_name=AXIS)
            if warmup_steps:  # critic warm-up: zero policy gradients leave Adam's update exactly 0
                frozen = adam_count(o) < warmup_steps
                grads = grads.replace(policy=jax.tree.map(lambda g: jnp.where(frozen, 0.0, g), grads.policy))
            updates, o = self.optimizer.update(grads, o, p)
            metrics = {**metrics, "kl": kl, "learning_rate": learning_rate(o)}
            return (o, optax.apply_updates(p, updates), kk), metrics

        mbs = jax.tree.map(shuffle, data)
        (opt_state, params, _), metrics = jax.lax.scan(minibatch, (opt_state, params, k_mb), mbs)
        return (opt_state, params, k), metrics

    def collect_step(self, ts: TrainingState, env: Any) -> Callable[[tuple, Any], tuple]:
        """``rollout``'s scan body: one control step of every slot of ``env`` under ``ts``'s policy.

        ``((env_state, key), _) -> ((env_state, key), (transition, sums))``; ``sums``: that step's
        ``rollout_sums.step_sums`` (``rollout``'s ``stats`` sum them).
        """
        policy = self.make_policy((ts.normalizer_params, ts.params.policy, ts.params.value))
        task = env.unwrapped
        layout = sum_layout(task)

        def env_step(c: tuple, _: Any) -> tuple:
            s, kk = c
            kk, k_act = jax.random.split(kk)
            action, extras = policy(s.obs, k_act)
            ns = env.step(s, action)
            tr = types.Transition(
                observation=s.obs,
                action=action,
                reward=ns.reward,
                discount=1.0 - ns.done,
                next_observation=ns.obs,
                extras={"policy_extras": extras, "state_extras": {"truncation": ns.info["truncation"]}},
            )
            return (ns, kk), (tr, step_sums(layout, task, ns))

        return env_step

    def rollout(
        self, ts: TrainingState, env_state: Any, key: jax.Array, env: Any, unrolls: int
    ) -> tuple[Any, types.Transition, jax.Array]:
        """Collect ``unrolls`` segments of ``unroll_length`` steps per env slot with the stochastic policy.

        Args:
            ts: replicated training state.
            env_state: this device's env slots (batched ``State``).
            key: this device's key.
            env: the batched env of this device's slots (``BatchedEnv``).
            unrolls: segments per env slot per iteration (``batch_size * num_minibatches / num_envs``).

        Returns:
            ``(env_state, data, stats)``: ``data`` = transitions, leaves ``(unrolls * envs, T, ...)``;
            ``stats`` = this device's sums of ``rollout_sums.step_sums`` (columns: ``sum_layout(task)``;
            the first three: reward, success numerator, success denominator).
        """
        env_step = self.collect_step(ts, env)

        def unroll(c: tuple, _: None) -> tuple:
            return jax.lax.scan(env_step, c, None, length=self.ppo.unroll_length)

        (env_state, _), (data, stats) = jax.lax.scan(unroll, (env_state, key), None, length=unrolls)
        return env_state, segments(data), stats.sum(axis=(0, 1))

    def prepare_update(self, ts: TrainingState, data: types.Transition) -> tuple[Any, types.Transition]:
        """``update``'s first part: the normaliser updated with ``data``'s observations.

        Also ``data`` with its value targets when those are fixed for the iteration (``value_targets =
        "iteration"``: from the critic that collected it).
        """
        normalizer = ts.normalizer_params
        if self.ppo.normalize_observations:
            normalizer = running_statistics.update(normalizer, data.observation, pmap_axis_name=AXIS)
        if self.ppo.value_targets == "iteration":
            data = self._with_targets(ts.params, normalizer, data)
        return normalizer, data

    def sgd_passes(self, carry: tuple, data: types.Transition, normalizer: Any, n: int) -> tuple:
        """``n`` SGD passes (``sgd_pass``) in one scan: ``(carry, metrics stacked over the passes)``."""
        return jax.lax.scan(lambda c, _: self.sgd_pass(c, data, normalizer), carry, None, length=n)

    def update(
        self, ts: TrainingState, data: types.Transition, key: jax.Array
    ) -> tuple[TrainingState, dict[str, jax.Array]]:
        """``prepare_update``, then ``num_updates_per_batch`` shuffled SGD passes over ``data``."""
        normalizer, data = self.prepare_update(ts, data)
        init = (ts.optimizer_state, ts.params, key)
        (opt_state, params, _), metrics = self.sgd_passes(
            init, data, normalizer, self.ppo.num_updates_per_batch
        )
        ts = TrainingState(optimizer_state=opt_state, params=params, normalizer_params=normalizer)
        return ts, jax.tree.map(jnp.mean, metrics)

    def iteration(
        self, ts: TrainingState, env_state: Any, key: jax.Array, env: Any, unrolls: int
    ) -> tuple[TrainingState, Any, dict[str, jax.Array], jax.Array]:
        """One PPO iteration: ``rollout`` then ``update``.

        Returns:
            ``(ts, env_state, loss_metrics, stats)`` (``stats`` as in ``rollout``).
        """
        k_roll, k_sgd = jax.random.split(key)
        env_state, data, stats = self.rollout(ts, env_state, k_roll, env, unrolls)
        ts, metrics = self.update(ts, data, k_sgd)
        return ts, env_state, metrics, stats


def learning_rate(opt_state: Any) -> jax.Array:
    """The learning rate held in ``make_learner``'s optimizer state (scalar)."""
    return opt_state[1].hyperparams["learning_rate"]


def adam_count(opt_state: Any) -> jax.Array:
    """Adam steps taken so far (int32 scalar; ``make_learner``'s optimizer state), one per minibatch."""
    return opt_state[1].inner_state[0].count


def set_learning_rate(opt_state: Any, lr: jax.Array) -> Any:
    """``opt_state`` with the learning rate ``lr`` (the next update uses it)."""
    adam = opt_state[1]
    new = adam._replace(hyperparams={**adam.hyperparams, "learning_rate": jnp.asarray(lr, jnp.float32)})
    return (opt_state[0], new)


def adapt_learning_rate(lr: jax.Array, kl: jax.Array, ppo: PPOConfig) -> jax.Array:
    """rsl-rl's KL-adaptive rule: / 1.5 above 2 x ``desired_kl``, x 1.5 below half of it, within bounds."""
    lr = jnp.where(kl > 2.0 * ppo.desired_kl, lr / 1.5, jnp.where(kl < 0.5 * ppo.desired_kl, lr * 1.5, lr))
    return jnp.clip(lr, ppo.min_learning_rate, ppo.max_learning_rate)


def make_learner(
    observation_size: int,
    action_size: int,
    ppo: PPOConfig,
    net: NetworkConfig,
    prior: Prior | None = None,
) -> Learner:
    """The learner for an env's sizes: brax networks and Adam after global-norm clipping (when configured).

    Adam's learning rate sits in the optimizer state (``optax.inject_hyperparams``), so the adaptive schedule
    can change it between minibatch steps (``learning_rate`` / ``set_learning_rate``).
    """
    networks = make_networks(observation_size, action_size, net, ppo.normalize_observations, prior)
    clip = optax.clip_by_global_norm(ppo.max_grad_norm) if ppo.max_grad_norm > 0 else optax.identity()
    optimizer = optax.chain(clip, optax.inject_hyperparams(optax.adam)(learning_rate=ppo.learning_rate))
    return Learner(
        networks=networks,
        make_policy=ppo_networks.make_inference_fn(networks),
        optimizer=optimizer,
        ppo=ppo,
        observation_size=observation_size,
    )
