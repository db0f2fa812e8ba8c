"""The env contract: the ``State`` pytree and the ``MjxEnv`` base class.

``State`` is our own ``flax.struct.dataclass`` (``data, obs, reward, done, metrics, info``), not brax's
``brax.envs.State``: brax's training loop never constructs or inspects the state type itself, it only reads
``obs``, ``reward``, ``done``, ``metrics`` and ``info`` and mutates the ``info``/``metrics`` dicts in its
``EvalWrapper``. Our wrappers (``bar_policy.envs.wrappers``) provide the keys brax PPO reads from ``info``
(``steps``, ``truncation``, ``episode_done``, ``episode_metrics``, ``time_out``), so brax's own
``envs.training.wrap`` (which needs ``pipeline_state`` and ``env.sys``) is not used.

Every env exposes pure ``reset(rng) -> State`` and ``step(state, action) -> State`` (unbatched; jit- and
vmap-able), and model-explicit twins ``reset_with_model(model, rng)`` / ``step_with_model(model, state,
action)`` that the domain-randomisation wrapper vmaps over a batch of randomised ``mjx.Model``s.

The seam between a task and the trainers is three members, so that the training code never names a task:

- ``task_name``: written to the policy file (``task_type`` / ``bar.task``).
- ``eval_ratios(metrics)``: what an evaluation reports, as ``name -> (numerator, denominator)`` per step;
  the evaluators sum both over steps and envs and report the ratio. ``success_rate`` is always present
  (it drives time-to-threshold); reach adds ``final_distance`` (m).
- ``task_metadata()``: the task's Humanoid Control keys (``body_names``, ``lookahead_steps``,
  ``dataset_repo_id``) for the exported file.
"""

from __future__ import annotations

import abc
from typing import Any

import jax
from flax import struct
from mujoco import mjx

__all__ = ["MjxEnv", "State", "eval_ratios"]


@struct.dataclass
class State:
    """One env's state (add a leading batch axis to every leaf when batched).

    Attributes:
        data: the ``mjx.Data`` after the last physics substep.
        obs: observation, shape ``(observation_size,)``, float32.
        reward: scalar reward of the last transition.
        done: 1.0 when the episode ended on this transition (float32, brax convention).
        metrics: named scalars logged by the trainer (``reward/<term>``, ``success``, ...).
        info: env bookkeeping carried between steps (targets, action buffer, rng, ...).
    """

    data: mjx.Data
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array]
    info: dict[str, Any]


class MjxEnv(abc.ABC):
    """Base class of the MJX envs: the model, timing and the pure reset/step pair."""

    @abc.abstractmethod
    def reset_with_model(self, model: mjx.Model, rng: jax.Array) -> State:
        """Reset one env on ``model``. ``rng``: a PRNG key, shape (2,)."""

    @abc.abstractmethod
    def step_with_model(self, model: mjx.Model, state: State, action: jax.Array) -> State:
        """Advance one control step on ``model``. ``action``: shape (action_size,)."""

    def reset(self, rng: jax.Array) -> State:
        """Reset one env on the nominal model. ``rng`` shape (2,); vmap for a batch."""
        return self.reset_with_model(self.mjx_model, rng)

    def step(self, state: State, action: jax.Array) -> State:
        """Advance one control step on the nominal model. ``action`` shape (action_size,), in [-1, 1]."""
        return self.step_with_model(self.mjx_model, state, action)

    @property
    @abc.abstractmethod
    def mj_model(self) -> Any:
        """The compiled C ``mujoco.MjModel``."""

    @property
    @abc.abstractmethod
    def mjx_model(self) -> mjx.Model:
        """The nominal ``mjx.Model`` (device arrays)."""

    @property
    @abc.abstractmethod
    def dt(self) -> float:
        """Control period, s."""

    @property
    @abc.abstractmethod
    def n_substeps(self) -> int:
        """Physics steps per control step."""

    @property
    @abc.abstractmethod
    def observation_size(self) -> int:
        """Length of ``State.obs``."""

    @property
    @abc.abstractmethod
    def action_size(self) -> int:
        """Length of the action vector."""

    task_name: str = "reach"
    """Task name written to exported policy files (``task_type``)."""

    def eval_ratios(self, metrics: dict[str, jax.Array]) -> dict[str, tuple[jax.Array, jax.Array]]:
        """Evaluation counts of one step: ``name -> (numerator, denominator)``, same shapes as the metrics.

        The default is reach's convention (see ``eval_ratios``); tasks override it.
        """
        return reach_eval_ratios(metrics)

    def task_metadata(self) -> dict[str, Any]:
        """Humanoid Control task keys for the policy file.

        ``body_names`` (tuple of str), ``lookahead_steps`` (int) and ``dataset_repo_id`` (str), empty for
        tasks without references; ``command_transition_s`` (float, s) for tasks whose commands move along
        ``tasks.reach.shared.transition_point``; ``song_lead_steps`` (int) for the piano's goal keys read
        ahead of the song (``tasks.piano.bank.PlaybackConfig``).
        """
        return {}

    @property
    def unwrapped(self) -> MjxEnv:
        """The env itself (wrappers forward this, as brax's ``Wrapper.unwrapped`` expects)."""
        return self

    @property
    def backend(self) -> str:
        """Physics backend name (read by brax's ``Wrapper.backend``)."""
        return "mjx"


def reach_eval_ratios(metrics: dict[str, jax.Array]) -> dict[str, tuple[jax.Array, jax.Array]]:
    """Reach's evaluation: success at the end of each target segment, and the distance there.

    ``success_rate`` = sum(``success_end``) / sum(``segment_end``); ``final_distance`` (m) = mean over
    segment ends of the two hands' mean distance. A metrics dict without segment keys falls back to the
    per-step ``success`` flag over all steps.
    """
    if "success_end" in metrics and "segment_end" in metrics:
        seg = metrics["segment_end"]
        out = {"success_rate": (metrics["success_end"], seg)}
        if "dist_left" in metrics and "dist_right" in metrics:
            out["final_distance"] = (0.5 * (metrics["dist_left"] + metrics["dist_right"]) * seg, seg)
        return out
    s = metrics["success"]
    return {"success_rate": (s, s * 0 + 1)}


def eval_ratios(env: Any, metrics: dict[str, jax.Array]) -> dict[str, tuple[jax.Array, jax.Array]]:
    """``env.eval_ratios(metrics)`` when the env defines it, else reach's convention (stand-in envs)."""
    fn = getattr(env, "eval_ratios", None)
    return fn(metrics) if fn is not None else reach_eval_ratios(metrics)
