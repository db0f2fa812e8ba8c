"""rsl-rl ``VecEnv`` over a batched MJX env: JAX steps under jit, tensors cross by DLPack (no host copies).

The jax side (the env wrapped for training exactly as for the brax backend, the jitted ``reset``, ``step``
and quality reduction, the reset keys) is ``rsl_rl.programs.EnvPrograms``, torch-free, so that it can be
built and its programs submitted to the compiler before torch is imported; this class is the torch side
over it (built from one, or building its own). Each ``step(actions)``:

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
``torch_bridge`` (a copy there is counted and logged, never silent); the per-step path
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
commands ``prior(obs) + residual`` (``rsl_rl.prior.commanded_action``, on the device, from the observation
the actor saw), and the quality figures see that commanded action. ``rsl_rl.prior`` explains why PPO is
unchanged by it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from bar_policy.obs.action_prior import Prior
from bar_policy.training.rsl_rl.programs import EnvPrograms
from bar_policy.training.rsl_rl.torch_bridge import jax_to_torch, torch_device_for_jax, torch_to_jax

__all__ = ["RslRlVecEnv", "torch_device_for_jax"]


class RslRlVecEnv(VecEnv):
    """A batch of ``num_envs`` copies of a ``bar_policy.envs`` env as an rsl-rl ``VecEnv``.

    Made over the env's jax side already built (``programs``: ``rsl_rl.programs.EnvPrograms``, e.g.
    compiling since ``prepare_rsl_rl``, before torch was imported; the trainer's form), or from the env
    itself (``from_env``, which builds them).

    Args:
        programs: the env's jax side (wrapped env, reset/step/quality programs, the reset keys).
        device: torch device; must be where jax's arrays live (``torch_device_for_jax()``).
        log_metrics: put the env's per-step metrics in ``extras["log"]`` (``Metrics/<name>``); off for
            an evaluation env, whose steps no rsl-rl logger reads.

    ``from_env``'s arguments:
        env: the unwrapped jax env.
        num_envs: batch size.
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)``, or None for the nominal model.
        seed: seed of the randomisation and of the resets.
        name: the programs' name prefix (``EnvPrograms``).
        quality: also measure the evaluation's safety and smoothness figures (``eval_quality``, as the
            brax evaluator does: ``quality/<figure>`` in ``take_stats()["quality"]``) on each slot's first
            episode; for an evaluation env (it keeps every step's chatter signal, episode_length x
            num_envs x joints).
        prior: the action prior, or None: ``step``'s actions are then residuals added to ``prior(obs)``
            of the current observations (``commanded_action``).

    The first reset runs when the state is first needed (``state``, ``get_observations``, ``step``), from
    the keys drawn at construction; a ``reset_all`` before it replaces it.

    Observations are returned as ``TensorDict({"policy": obs})`` (shape ``(num_envs, obs)``); extras carry
    ``time_outs`` (truncations) for rsl-rl's bootstrapping.

    Accumulated on the device since the last ``take_stats`` (or reset): ``reward`` and ``success``
    (numerator, denominator of the task's ``success_rate``) summed over every step and env, as the training
    line reports them; and per env slot the return and every ratio of ``eval_ratios`` counted only while
    the slot's first episode is alive (up to and including its first ``done``), as an evaluation counts;
    and the training sums of every step and env that the brax rollout logs (``rollout_sums.step_sums``:
    reward terms, the task's ratios, finished episodes and their lengths).
    """

    @classmethod
    def from_env(
        cls,
        env: Any,
        num_envs: int,
        *,
        wrap_fn: Callable[..., Any],
        randomizer: Callable[..., Any] | None = None,
        seed: int = 0,
        device: str | None = None,
        name: str = "env",
        log_metrics: bool = True,
        quality: bool = False,
        prior: Prior | None = None,
    ) -> RslRlVecEnv:
        """``num_envs`` copies of ``env``, its jax side built here (``EnvPrograms``); see the class."""
        programs = EnvPrograms(
            env,
            num_envs,
            wrap_fn=wrap_fn,
            randomizer=randomizer,
            seed=seed,
            quality=quality,
            prior=prior,
            name=name,
        )
        return cls(programs, device=device, log_metrics=log_metrics)

    def __init__(self, programs: EnvPrograms, *, device: str | None = None, log_metrics: bool = True) -> None:
        self.programs = programs
        """The jax side: wrapped env, reset/step/quality programs, the reset keys."""
        self.num_envs = programs.num_envs
        self.task = programs.task
        """The unwrapped env (its ``eval_ratios`` define the evaluation)."""
        self.num_actions = programs.num_actions
        self.num_obs = programs.num_obs
        self.max_episode_length = programs.max_episode_length
        self.device = device or torch_device_for_jax()
        self.cfg = getattr(self.task, "config", {})
        self.log_metrics = log_metrics
        self.quality = programs.quality
        self.prior = programs.prior
        """The action prior added to ``step``'s actions, or None."""
        self._state: Any = None
        self._stats: dict[str, Any] = {}

    @property
    def _step(self) -> Callable[..., Any]:
        """The batched step ``(state, actions, stats)`` on the env's reward weights (exposed for tests).

        ``EnvPrograms.step``: the jitted step, or the compiler's executable, with the weights appended.
        """
        return self.programs.step

    @property
    def state(self) -> Any:
        """The batched env state (the first reset runs here, when first needed)."""
        self._start()
        return self._state

    @state.setter
    def state(self, value: Any) -> None:
        self._state = value

    @property
    def stats(self) -> dict[str, Any]:
        """The device-side accumulators (see the class docstring)."""
        self._start()
        return self._stats

    @stats.setter
    def stats(self, value: dict[str, Any]) -> None:
        self._stats = value

    def _start(self) -> None:
        """Run the first reset (from the keys drawn at construction) unless a reset already ran."""
        if self._state is None:
            self._set_reset(self.programs.first_keys)

    def _set_reset(self, keys: jax.Array) -> None:
        self._state, self._stats = self.programs.reset(keys)
        self._fresh_stats = self._stats  # immutable device arrays: reused as the zero point

    # -- VecEnv -----------------------------------------------------------------------------------
    def reset_all(self, seed: int | None = None) -> Any:
        """Reset every env (fresh keys; ``seed`` picks them explicitly) and the accumulators."""
        self._set_reset(self.programs.next_keys(seed))
        return self._state

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
            {name: (num, den)}, "window": {column: float}}``: sums as described in the class docstring
            (``window``: the training sums of every step, ``rollout_sums``' columns); with ``quality``, also
            ``"quality": {"quality/<figure>": float}`` (``eval_quality.finish``'s figures).
        """
        dev = dict(self.stats)
        if self.quality:
            dev.pop("t")
            dev["quality"] = self.programs.finish_quality(dev["quality"], dev.pop("signals"))
        host = jax.device_get(dev)
        self.stats = self._fresh_stats
        out = {
            "reward": float(host["reward"]),
            "success": (float(host["success"][0]), float(host["success"][1])),
            "return": np.asarray(host["return"]),
            "ratios": {k: (float(np.sum(n)), float(np.sum(d))) for k, (n, d) in host["ratios"].items()},
            "window": self.programs.layout.named(host["window"]),
        }
        if self.quality:
            out["quality"] = {k: float(v) for k, v in host["quality"].items()}
        return out

    def jax_actions(self, actions: torch.Tensor) -> jax.Array:
        """The zero-copy jax view of a torch action batch (exposed for tests)."""
        return torch_to_jax(actions)
