"""Batched training wrapper: vmap over envs (and randomised models), episode bookkeeping, auto-reset.

``BatchedEnv`` is what brax's ``ppo.train`` needs (pass ``wrap_env_fn=wrap_for_brax_training``) and what an
rsl-rl ``VecEnv`` wraps: ``reset(keys[B, 2]) -> State`` and ``step(State, action[B, n]) -> State``, both
pure and jit-able, all leaves with a leading batch axis B.

Info keys added on top of the env's (brax PPO reads them as ``state_extras``):

- ``steps``: control steps in the current episode (float32; reset to 0 on the step after ``done``).
- ``truncation``: 1 when the episode ended by time limit (not by the env); ``time_out``: the same.
- ``episode_done``: ``done`` of this step.
- ``episode_metrics``: per-episode running sums of ``sum_reward``, ``length`` and every metric.
- ``sampler`` (tasks with an adaptive start sampler, auto-reset on): this device's decaying failure and
  visit counts per start bin, spread over the env axis (``envs/sampling.py``); each auto-reset draws its
  start bin from them.

Auto-reset: when ``done``, the returned state carries the terminal ``reward``/``done``/``metrics`` but the
``data``/``obs``/env ``info`` of a fresh episode (new targets, new per-episode actuator samples, rng
derived from the env's own key). The reset is computed only when at least one env is done (a batch-level
``lax.cond``, a real branch on GPU), so the common steps pay nothing for it.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from mujoco import mjx

from bar_policy.envs.base import MjxEnv, State
from bar_policy.envs.sampling import pack, unpack

__all__ = ["WRAPPER_INFO_KEYS", "BatchedEnv", "make_batched_env", "wrap_for_brax_training"]

WRAPPER_INFO_KEYS = ("steps", "truncation", "time_out", "episode_done", "episode_metrics", "sampler")
"""Info keys owned by the wrapper (stripped before the inner env's step)."""

_RESET_SALT = 0x5EED
_START_SALT = 0xB1A5


class BatchedEnv:
    """vmap + domain randomisation + episode length + auto-reset around an ``MjxEnv``."""

    def __init__(
        self,
        env: MjxEnv,
        *,
        episode_length: int | None = None,
        action_repeat: int = 1,
        randomization_fn: Callable[[mjx.Model], tuple[mjx.Model, Any]] | None = None,
        auto_reset: bool = True,
    ) -> None:
        """Wrap ``env``.

        Args:
            env: the unbatched env.
            episode_length: control steps per episode (default: ``env.episode_length``).
            action_repeat: env steps per ``step`` call with the same action (rewards summed).
            randomization_fn: ``model -> (batched_model, in_axes)``, the env's randomiser with its ``rng``
                already bound (brax binds it with ``functools.partial(fn, rng=keys)``); the batch size of
                the randomised model must equal the batch size given to ``reset``. None: nominal model.
            auto_reset: reset finished envs inside ``step`` (training). False leaves a finished env in its
                terminal state (an evaluator that runs one episode per env and masks what follows ``done``);
                the step then holds no copy of the reset, a smaller program to compile.
        """
        length = episode_length if episode_length is not None else getattr(env, "episode_length", None)
        if length is None or int(length) < 1:
            raise ValueError(f"episode_length must be a positive number of steps, got {length!r}")
        if int(action_repeat) < 1:
            raise ValueError(f"action_repeat must be >= 1, got {action_repeat!r}")
        self.env = env
        self.episode_length = int(length)
        self.action_repeat = int(action_repeat)
        self.auto_reset = bool(auto_reset)
        self._bins = int(getattr(env, "sampler_bins", 0)) if self.auto_reset else 0
        if randomization_fn is None:
            self._model, self._in_axes = env.mjx_model, None
        else:
            self._model, self._in_axes = randomization_fn(env.mjx_model)

    def with_env(self, env: MjxEnv) -> BatchedEnv:
        """A shallow copy stepping ``env`` in place of ``self.env``: the same settings and randomised models.

        For a copy of the same env with another config (``envs.reward_weights.with_weights``): nothing this
        wrapper built at construction may depend on what differs.
        """
        out = copy.copy(self)
        out.env = env
        return out

    # -- brax Env surface --------------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        """Per-env observation length."""
        return self.env.observation_size

    @property
    def action_size(self) -> int:
        """Per-env action length."""
        return self.env.action_size

    @property
    def unwrapped(self) -> MjxEnv:
        """The inner env."""
        return self.env

    @property
    def backend(self) -> str:
        """Physics backend name."""
        return self.env.backend

    @property
    def model(self) -> mjx.Model:
        """The (possibly batched) model the envs step on."""
        return self._model

    # -- pure functions ----------------------------------------------------------------------------
    def _reset_envs(self, rng: jax.Array, start_bins: jax.Array | None = None) -> State:
        if start_bins is None:
            return jax.vmap(self.env.reset_with_model, in_axes=(self._in_axes, 0))(self._model, rng)
        return jax.vmap(self.env.reset_with_model, in_axes=(self._in_axes, 0, 0))(
            self._model, rng, start_bins
        )

    def reset(self, rng: jax.Array) -> State:
        """Reset a batch. ``rng``: keys, shape (B, 2). Returns a State with leading axis B."""
        state = self._reset_envs(rng)
        zeros = jnp.zeros(rng.shape[:-1])
        ep_metrics = {"sum_reward": zeros, "length": zeros, **{k: zeros for k in state.metrics}}
        info = {
            **state.info,
            "steps": zeros,
            "truncation": zeros,
            "time_out": zeros,
            "episode_done": zeros,
            "episode_metrics": ep_metrics,
        }
        if self._bins:
            info["sampler"] = pack(jnp.zeros((2, self._bins)), rng.shape[0])
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        """Step a batch. ``action``: shape (B, n), in [-1, 1]. Auto-resets finished envs."""
        info = state.info
        env_info = {k: v for k, v in info.items() if k not in WRAPPER_INFO_KEYS and k != "eval_metrics"}
        inner = state.replace(info=env_info)

        def one(model: mjx.Model, s: State, a: jax.Array) -> State:
            if self.action_repeat == 1:
                return self.env.step_with_model(model, s, a)

            def body(carry: State, _: None) -> tuple[State, jax.Array]:
                ns = self.env.step_with_model(model, carry, a)
                return ns, ns.reward

            ns, rews = jax.lax.scan(body, s, None, length=self.action_repeat)
            return ns.replace(reward=jnp.sum(rews, axis=0))

        ns = jax.vmap(one, in_axes=(self._in_axes, 0, 0))(self._model, inner, action)

        steps = jnp.where(state.done > 0, 0.0, info["steps"]) + self.action_repeat
        timeout = steps >= self.episode_length
        truncation = (timeout & (ns.done == 0)).astype(jnp.float32)
        done = jnp.maximum(ns.done, timeout.astype(jnp.float32))

        keep = 1.0 - info["episode_done"]
        old = info["episode_metrics"]
        ep_metrics = {
            "sum_reward": old["sum_reward"] * keep + ns.reward,
            "length": old["length"] * keep + self.action_repeat,
            **{k: old[k] * keep + v for k, v in ns.metrics.items()},
        }

        counts = None
        if self._bins:
            counts = self.env.sampler_update(unpack(info["sampler"], self._bins), ns.info, ns.done)  # type: ignore[attr-defined]

        def with_reset(s: State) -> State:
            keys = jax.vmap(lambda k: jax.random.fold_in(k, _RESET_SALT))(s.info["rng"])
            start_bins = None
            if counts is not None:
                logp = jnp.log(self.env.start_probabilities(counts))  # type: ignore[attr-defined]
                start_keys = jax.vmap(lambda k: jax.random.fold_in(k, _START_SALT))(keys)
                start_bins = jax.vmap(lambda k: jax.random.categorical(k, logp))(start_keys)
            fresh = self._reset_envs(keys, start_bins)

            def sel(a: jax.Array, b: jax.Array) -> jax.Array:
                return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)) > 0, a, b)

            return s.replace(
                data=jax.tree.map(sel, fresh.data, s.data),
                obs=sel(fresh.obs, s.obs),
                info=jax.tree.map(sel, fresh.info, s.info),
            )

        if self.auto_reset:
            ns = jax.lax.cond(jnp.any(done > 0), with_reset, lambda s: s, ns)
        new_info = {
            **ns.info,
            "steps": steps,
            "truncation": truncation,
            "time_out": truncation,
            "episode_done": done,
            "episode_metrics": ep_metrics,
        }
        if counts is not None:
            new_info["sampler"] = pack(counts, action.shape[0])
        return ns.replace(done=done, info=new_info)


def wrap_for_brax_training(
    env: MjxEnv,
    episode_length: int | None = None,
    action_repeat: int = 1,
    randomization_fn: Callable[[mjx.Model], tuple[mjx.Model, Any]] | None = None,
    *,
    auto_reset: bool = True,
) -> BatchedEnv:
    """``wrap_env_fn`` for ``brax.training.agents.ppo.train``: same keywords as brax's ``envs.training.wrap``.

    ``auto_reset=False`` (not a brax keyword) builds an evaluation batch without the in-step reset.

    Example::

        env = envs.load("LiteReach")
        make_inference_fn, params, metrics = ppo.train(
            environment=env,
            wrap_env_fn=envs.wrap_for_brax_training,
            randomization_fn=envs.get_randomizer("LiteReach", env.config),
            episode_length=env.episode_length,
            num_envs=8192, ...)
    """
    return BatchedEnv(
        env,
        episode_length=episode_length,
        action_repeat=action_repeat,
        randomization_fn=randomization_fn,
        auto_reset=auto_reset,
    )


def make_batched_env(
    env: MjxEnv,
    num_envs: int,
    *,
    seed: int = 0,
    randomize: bool = True,
    episode_length: int | None = None,
) -> tuple[BatchedEnv, Callable[[jax.Array], State], Callable[[State, jax.Array], State]]:
    """A batched env and its jitted ``reset``/``step``, for a non-brax trainer (e.g. an rsl-rl ``VecEnv``).

    Args:
        env: the unbatched env (``bar_policy.envs.load(...)``).
        num_envs: batch size B.
        seed: seed of the model randomisation keys.
        randomize: apply the env's model-level randomiser (``get_randomizer`` with ``env.config``).
        episode_length: control steps per episode (default ``env.episode_length``).

    Returns:
        ``(batched, reset, step)``: ``reset(keys[B, 2]) -> State`` and ``step(State, action[B, n]) -> State``,
        both ``jax.jit``-ed, ``step`` donating the input state (do not reuse it after the call). Every leaf
        stays on the device: read ``state.obs``, ``state.reward``, ``state.done``,
        ``state.info["truncation"]`` (rsl-rl's ``time_outs``) and ``state.metrics`` through DLPack
        (``torch.from_dlpack(state.obs)``) and pass actions back the same way (``jax.dlpack.from_dlpack``).
    """
    randomization_fn = None
    if randomize:
        from bar_policy.envs.randomize import make_randomizer

        keys = jax.random.split(jax.random.PRNGKey(seed), num_envs)
        randomization_fn = functools.partial(make_randomizer(env.config), rng=keys)  # type: ignore[attr-defined]
    batched = BatchedEnv(env, episode_length=episode_length, randomization_fn=randomization_fn)
    return batched, jax.jit(batched.reset), jax.jit(batched.step, donate_argnums=(0,))
