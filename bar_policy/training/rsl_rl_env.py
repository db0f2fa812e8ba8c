"""rsl-rl ``VecEnv`` over a batched MJX env: JAX steps under jit, tensors cross by DLPack (no host copies).

The jax env is wrapped for training (batch, episode truncation, auto-reset, domain randomisation) exactly
as for the brax backend, and ``reset``/``step`` are jitted once. Each ``step(actions)``:

1. turns the torch action tensor into a jax array with ``jax.dlpack.from_dlpack`` (zero copy, same device;
   jax's stream waits on torch's through an event, the host does not),
2. runs the jitted batched step, which also adds this step's logging sums to device-side accumulators,
3. hands ``obs``, ``reward``, ``done`` and ``truncation`` back with ``torch.from_dlpack`` (zero copy; torch's
   stream waits on jax's).

Nothing in a step waits for the device: the logged sums (reward, the task's ``eval_ratios``) stay on the
device until ``take_stats`` reads them once per iteration or evaluation. The jax state is never donated,
so the torch views of its buffers stay valid until rsl-rl copies them into its rollout storage. Torch must
run on the device jax uses (``cuda`` for a GPU jax, else ``cpu``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from bar_policy.envs.base import eval_ratios
from bar_policy.training.startup import Compiler

__all__ = ["RslRlVecEnv", "torch_device_for_jax"]


def torch_device_for_jax() -> str:
    """The torch device that shares memory with jax's default device (``cuda:N`` or ``cpu``)."""
    dev = jax.local_devices()[0]
    return f"cuda:{dev.id}" if dev.platform == "gpu" else "cpu"


def _to_torch(x: jax.Array) -> torch.Tensor:
    return torch.from_dlpack(x)


def _to_jax(t: torch.Tensor) -> jax.Array:
    return jax.dlpack.from_dlpack(t.detach().contiguous())


class RslRlVecEnv(VecEnv):
    """A batch of ``num_envs`` copies of a ``bar_policy.envs`` env as an rsl-rl ``VecEnv``.

    Args:
        env: the unwrapped jax env.
        num_envs: batch size.
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)``, or None for the nominal model.
        seed: seed of the randomisation and of the resets.
        device: torch device; must be where jax's arrays live (``torch_device_for_jax()``).
        compiler: compile the batched step ahead of time on this ``startup.Compiler``'s threads (as
            ``name``), instead of at the first ``step``.
        name: the step program's name in ``compiler``.

    Observations are returned as ``TensorDict({"policy": obs})`` (shape ``(num_envs, obs)``); extras carry
    ``time_outs`` (truncations) for rsl-rl's bootstrapping.

    Accumulated on the device since the last ``take_stats`` (or reset): ``reward`` and ``success``
    (numerator, denominator of the task's ``success_rate``) summed over every step and env, as the training
    line reports them; and per env slot the return and every ratio of ``eval_ratios`` counted only while
    the slot's first episode is alive (up to and including its first ``done``), as an evaluation counts.
    """

    def __init__(
        self,
        env: Any,
        num_envs: int,
        *,
        wrap_fn: Callable[..., Any],
        randomizer: Callable[..., Any] | None = None,
        seed: int = 0,
        device: str | None = None,
        compiler: Compiler | None = None,
        name: str = "env step",
    ) -> None:
        self.num_envs = int(num_envs)
        self.task = env
        """The unwrapped env (its ``eval_ratios`` define the evaluation)."""
        self.num_actions = int(env.action_size)
        self.num_obs = int(env.observation_size)
        self.max_episode_length = int(env.episode_length)
        self.device = device or torch_device_for_jax()
        self.cfg = getattr(env, "config", {})
        key = jax.random.PRNGKey(seed)
        k_rand, self._key = jax.random.split(key)
        rfn = None
        if randomizer is not None:
            rfn = functools.partial(randomizer, rng=jax.random.split(k_rand, self.num_envs))
        self._env = wrap_fn(
            env, episode_length=self.max_episode_length, action_repeat=1, randomization_fn=rfn
        )
        self._reset = jax.jit(self._reset_fn)
        self.stats: dict[str, Any] = {}
        self.state = self.reset_all()
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        step = jax.jit(self._step_fn)
        self._step: Callable[..., Any] = step
        if compiler is not None:
            # Traced now, compiled on a worker thread: several envs' steps compile side by side.
            actions = jax.ShapeDtypeStruct((self.num_envs, self.num_actions), jnp.float32)
            compiler.submit(name, step, self.state, actions, self.stats)
            self._step = lambda *args: compiler.get(name)(*args)

    # -- jitted pure functions ---------------------------------------------------------------------
    def _reset_fn(self, keys: jax.Array) -> tuple[Any, dict[str, Any]]:
        state = self._env.reset(keys)
        ratios = eval_ratios(self.task, state.metrics)  # a reset's metrics have the step's keys
        zeros = jnp.zeros(self.num_envs)
        stats = {
            "reward": jnp.zeros(()),
            "success": (jnp.zeros(()), jnp.zeros(())),
            "alive": zeros + 1.0,
            "return": zeros,
            "ratios": {k: (zeros, zeros) for k in ratios},
        }
        return state, stats

    def _step_fn(self, state: Any, actions: jax.Array, stats: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        ns = self._env.step(state, actions)
        ratios = eval_ratios(self.task, ns.metrics)
        num, den = ratios["success_rate"]
        alive = stats["alive"]
        stats = {
            "reward": stats["reward"] + ns.reward.sum(),
            "success": (stats["success"][0] + num.sum(), stats["success"][1] + den.sum()),
            "alive": alive * (1.0 - ns.done),
            "return": stats["return"] + ns.reward * alive,
            "ratios": {
                k: (stats["ratios"][k][0] + n * alive, stats["ratios"][k][1] + d * alive)
                for k, (n, d) in ratios.items()
            },
        }
        return ns, stats

    # -- VecEnv -----------------------------------------------------------------------------------
    def reset_all(self, seed: int | None = None) -> Any:
        """Reset every env (fresh keys; ``seed`` picks them explicitly) and the accumulators."""
        if seed is None:
            self._key, k = jax.random.split(self._key)
        else:
            k = jax.random.PRNGKey(seed)
        self.state, self.stats = self._reset(jax.random.split(k, self.num_envs))
        self._fresh_stats = self.stats  # immutable device arrays: reused as the zero point
        return self.state

    def get_observations(self) -> TensorDict:
        """Current observations, ``{"policy": (num_envs, obs)}``."""
        return TensorDict(
            {"policy": _to_torch(self.state.obs)}, batch_size=[self.num_envs], device=self.device
        )

    @property
    def metrics(self) -> dict[str, jax.Array]:
        """The env metrics of the last step (jax arrays, shape (num_envs,))."""
        return self.state.metrics

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Step every env with ``actions`` (num_envs, num_actions); returns obs, reward, done, extras."""
        self.state, self.stats = self._step(self.state, _to_jax(actions.to(torch.float32)), self.stats)
        obs = self.get_observations()
        reward = _to_torch(self.state.reward)
        done = _to_torch(self.state.done)
        extras = {"time_outs": _to_torch(self.state.info["truncation"]), "log": {}}
        return obs, reward, done, extras

    def take_stats(self) -> dict[str, Any]:
        """The accumulated sums on the host (one device sync), then zero them (``alive`` restarts at 1).

        Returns:
            ``{"reward": float, "success": (num, den), "return": np.ndarray (num_envs,), "ratios":
            {name: (num, den)}}``: sums as described in the class docstring.
        """
        host = jax.device_get(self.stats)
        self.stats = self._fresh_stats
        return {
            "reward": float(host["reward"]),
            "success": (float(host["success"][0]), float(host["success"][1])),
            "return": np.asarray(host["return"]),
            "ratios": {k: (float(np.sum(n)), float(np.sum(d))) for k, (n, d) in host["ratios"].items()},
        }

    def jax_actions(self, actions: torch.Tensor) -> jax.Array:
        """The zero-copy jax view of a torch action batch (exposed for tests)."""
        return _to_jax(actions)
