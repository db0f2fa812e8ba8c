"""rsl-rl ``VecEnv`` over a batched MJX env: JAX steps under jit, tensors cross by DLPack (no host copies).

The jax env is wrapped for training (batch, episode truncation, auto-reset, domain randomisation) exactly
as for the brax backend, and ``reset``/``step`` are jitted once. Each ``step(actions)``:

1. turns the torch action tensor into a jax array with ``jax.dlpack.from_dlpack`` (zero copy, same device;
   jax's stream waits on torch's through an event, the host does not),
2. runs the jitted batched step, which also adds this step's logging sums to device-side accumulators,
3. hands ``obs``, ``reward``, ``done`` and ``truncation`` back with ``torch.from_dlpack`` (zero copy; torch's
   stream waits on jax's).

Buffer lifetimes on a GPU: a torch view keeps its jax buffer alive (the DLPack capsule holds it), and
when the view is dropped jax may reuse the memory for later work on its stream. That later work is
ordered after torch's reads: every jitted step waits (on the device) for the torch stream that produced
its actions, and those come after rsl-rl's storage copied the previous observations on the same stream.

Nothing in a step waits for the device: the logged sums (reward, the task's ``eval_ratios``) stay on the
device until ``take_stats`` reads them once per iteration or evaluation. The jax state is never donated,
so the torch views of its buffers stay valid until rsl-rl copies them into its rollout storage. Torch must
run on the device jax uses (``cuda`` for a GPU jax, else ``cpu``). Every crossing goes through
``bar_policy.training.torch_bridge`` (a copy there is counted and logged, never silent); the per-step path
has no numpy and no ``device_get``.

rsl-rl 5.x ``VecEnv`` contract (``rsl_rl/env/vec_env.py``): ``get_observations() -> TensorDict``;
``step(actions) -> (obs TensorDict, rewards (N,), dones (N,), extras)`` with ``extras["time_outs"]``
(bootstrapped by ``PPO.process_env_step``) and ``extras["log"]`` (``rsl_rl.utils.logger.Logger`` averages
each entry over the iteration's steps and envs; a key with a ``/`` is written as is). ``extras["log"]``
holds ``Metrics/<name>``: the env's per-step metrics (reward terms, distances, success), as zero-copy
tensors, so ``OnPolicyRunner.learn`` on this env logs them as its users know; the episode return and
length come from rsl-rl's own logger (``Train/mean_reward``, ``Train/mean_episode_length``).
``episode_length_buf`` is the wrapper's step counter (read and written through the bridge), so the
runner's ``init_at_random_ep_len`` works.

With an action prior (``prior=``), the actions ``step`` is given are the actor's residual: the jitted step
commands ``prior(obs) + residual`` (``rsl_rl_prior.commanded_action``, on the device, from the observation
the actor saw), and the quality figures see that commanded action. ``rsl_rl_prior`` explains why PPO is
unchanged by it.
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
from bar_policy.obs.action_prior import Prior, check_fits
from bar_policy.training import eval_quality
from bar_policy.training.parallel import AXIS
from bar_policy.training.rsl_rl_prior import commanded_action
from bar_policy.training.startup import Compiler
from bar_policy.training.torch_bridge import jax_to_torch, torch_device_for_jax, torch_to_jax

__all__ = ["RslRlVecEnv", "torch_device_for_jax"]


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
        log_metrics: put the env's per-step metrics in ``extras["log"]`` (``Metrics/<name>``); off for
            an evaluation env, whose steps no rsl-rl logger reads.
        quality: also measure the evaluation's safety and smoothness figures (``eval_quality``, as the
            brax evaluator does: ``quality/<figure>`` in ``take_stats()["quality"]``) on each slot's first
            episode; for an evaluation env (it keeps every step's chatter signal, episode_length x
            num_envs x joints).
        prior: the action prior, or None: ``step``'s actions are then residuals added to ``prior(obs)``
            of the current observations (``commanded_action``).

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
        log_metrics: bool = True,
        quality: bool = False,
        prior: Prior | None = None,
    ) -> None:
        self.num_envs = int(num_envs)
        self.task = env
        """The unwrapped env (its ``eval_ratios`` define the evaluation)."""
        self.num_actions = int(env.action_size)
        self.num_obs = int(env.observation_size)
        self.max_episode_length = int(env.episode_length)
        self.device = device or torch_device_for_jax()
        self.cfg = getattr(env, "config", {})
        self.log_metrics = log_metrics
        self.quality = quality
        if prior is not None:
            check_fits(prior, self.num_obs, self.num_actions)
        self.prior = prior
        """The action prior added to ``step``'s actions, or None."""
        key = jax.random.PRNGKey(seed)
        k_rand, self._key = jax.random.split(key)
        rfn = None
        if randomizer is not None:
            rfn = functools.partial(randomizer, rng=jax.random.split(k_rand, self.num_envs))
        self._env = wrap_fn(
            env, episode_length=self.max_episode_length, action_repeat=1, randomization_fn=rfn
        )
        self._reset = jax.jit(self._reset_fn)
        self._quality = jax.jit(self._quality_fn)
        self.stats: dict[str, Any] = {}
        self.state = self.reset_all()
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
        if self.quality:
            n = self.num_actions
            stats["quality"] = eval_quality.init(self.num_envs, n)
            stats["signals"] = jnp.zeros((self.max_episode_length, self.num_envs, n))
            stats["t"] = jnp.zeros((), jnp.int32)
        return state, stats

    def _step_fn(self, state: Any, actions: jax.Array, stats: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
        stats_in = stats
        actions = commanded_action(self.prior, state.obs, actions)  # the observation the actor saw
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
        if self.quality:  # as Learner.evaluate: the applied action's signals, before the step
            t, task, f32 = stats_in["t"], self.task, lambda x: jnp.asarray(x, jnp.float32)
            sig = jax.vmap(task.quality_signals)(state, actions)
            robot = task.robot
            limits = {"cap": f32(robot.torque_cap), "lower": f32(robot.lower), "upper": f32(robot.upper)}
            terminated = ns.done * (1.0 - ns.info["truncation"])
            first = t == 0
            qc, _ = eval_quality.update(
                stats_in["quality"], sig, alive, terminated, first, dt=task.dt, **limits
            )
            last = self.max_episode_length - 1
            stats["quality"] = qc
            stats["signals"] = stats_in["signals"].at[jnp.minimum(t, last)].set(sig["signal"])
            stats["t"] = t + 1
        return ns, stats

    def _quality_fn(self, qc: dict[str, jax.Array], signals: jax.Array) -> dict[str, jax.Array]:
        # eval_quality.finish reduces over the mesh axis: a vmap of size 1 names it (the sums are this
        # device's). Chatter is measured over every tick of ``signals``: an evaluation steps all of them.
        one = jax.tree.map(lambda x: x[None], (qc, signals))
        out = jax.vmap(lambda q, s: eval_quality.finish(q, s, self.task.dt), axis_name=AXIS)(*one)
        return jax.tree.map(lambda x: x[0], out)

    # -- VecEnv -----------------------------------------------------------------------------------
    def reset_all(self, seed: int | None = None) -> Any:
        """Reset every env (fresh keys; ``seed`` picks them explicitly) and the accumulators."""
        if seed is None:
            self._key, k = jax.random.split(self._key)
        else:
            k = jax.random.PRNGKey(seed)
        # Committed to jax's device (as the step's outputs are: its actions come from torch, committed):
        # the step then sees one signature from the first call on (an uncommitted reset state compiled
        # the jitted step a second time on the second call).
        keys = jax.device_put(jax.random.split(k, self.num_envs), jax.local_devices()[0])
        self.state, self.stats = self._reset(keys)
        self._fresh_stats = self.stats  # immutable device arrays: reused as the zero point
        return self.state

    def get_observations(self) -> TensorDict:
        """Current observations, ``{"policy": (num_envs, obs)}``."""
        return TensorDict(
            {"policy": jax_to_torch(self.state.obs)}, batch_size=[self.num_envs], device=self.device
        )

    @property
    def episode_length_buf(self) -> torch.Tensor:
        """Control steps into each env's episode, (num_envs,) float32: a view of the wrapper's ``steps``."""
        return jax_to_torch(self.state.info["steps"])

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        # OnPolicyRunner.learn(init_at_random_ep_len=True) assigns random lengths: the wrapper's counter
        # takes them (as float32, its dtype), so time-outs come spread over the first episode.
        steps = torch_to_jax(value.to(torch.float32))
        self.state = self.state.replace(info={**self.state.info, "steps": steps})

    @property
    def metrics(self) -> dict[str, jax.Array]:
        """The env metrics of the last step (jax arrays, shape (num_envs,))."""
        return self.state.metrics

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        """Step every env with ``actions`` (num_envs, num_actions); returns obs, reward, done, extras.

        With ``prior``, ``actions`` are residuals: the env is commanded ``prior(obs) + actions``.
        """
        self.state, self.stats = self._step(self.state, torch_to_jax(actions.to(torch.float32)), self.stats)
        obs = self.get_observations()
        reward = jax_to_torch(self.state.reward)
        done = jax_to_torch(self.state.done)
        log = {}
        if self.log_metrics:
            log = {f"Metrics/{k}": jax_to_torch(v) for k, v in self.state.metrics.items()}
        extras = {"time_outs": jax_to_torch(self.state.info["truncation"]), "log": log}
        return obs, reward, done, extras

    def take_stats(self) -> dict[str, Any]:
        """The accumulated sums on the host (one device sync), then zero them (``alive`` restarts at 1).

        Returns:
            ``{"reward": float, "success": (num, den), "return": np.ndarray (num_envs,), "ratios":
            {name: (num, den)}}``: sums as described in the class docstring; with ``quality``, also
            ``"quality": {"quality/<figure>": float}`` (``eval_quality.finish``'s figures).
        """
        dev = dict(self.stats)
        if self.quality:
            dev.pop("t")
            dev["quality"] = self._quality(dev["quality"], dev.pop("signals"))
        host = jax.device_get(dev)
        self.stats = self._fresh_stats
        out = {
            "reward": float(host["reward"]),
            "success": (float(host["success"][0]), float(host["success"][1])),
            "return": np.asarray(host["return"]),
            "ratios": {k: (float(np.sum(n)), float(np.sum(d))) for k, (n, d) in host["ratios"].items()},
        }
        if self.quality:
            out["quality"] = {k: float(v) for k, v in host["quality"].items()}
        return out

    def jax_actions(self, actions: torch.Tensor) -> jax.Array:
        """The zero-copy jax view of a torch action batch (exposed for tests)."""
        return torch_to_jax(actions)
