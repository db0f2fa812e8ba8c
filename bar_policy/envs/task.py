"""The contract between the robot env (``robot.py``) and a task: the hooks a task fills and what they see.

A task's env module (``tasks/<task>/env.py``) subclasses ``LiteRobotEnv`` and implements ``TaskHooks``:

- ``task_reset(model, key) -> (info, q_init, qvel_init)``: the task's entries of ``State.info`` for a new
  episode and the initial joint state (the robot env adds the initial-pose noise);
- ``task_step(transition) -> TaskStep``: the step's task signals (named quantities the term tables read),
  metrics and the task's info for the next state;
- ``reward_terms() -> (RewardTerm, ...)`` and ``termination_terms() -> (TerminationTerm, ...)``: the task's
  term table (``tasks/<task>/term_table.py``, rows of ``envs.term_table``) for the env's current config;
  the robot env evaluates them on the robot's and the task's signals, sums the rewards and ends the
  episode when a termination fires;
- ``task_obs(model, data, q_meas, info) -> inputs``: the task's observation inputs (term name -> array);
- ``metric_keys``: the names of the task's metrics.

Hooks are pure functions of their arguments (jit- and vmap-able, unbatched). Joint vectors a hook gets or
returns (``q_init``, ``q_meas``, ``action``) are the robot's, shape (n,), canonical order. ``data`` is the
whole scene's state: in a task's scene (``LiteRobotEnv(..., scene=)``, docs/scenes.md) it holds the task's
joints too, so read the robot's with ``robot_q(data)`` / ``robot_dq(data)``, not ``data.qpos``.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import jax
from mujoco import mjx

from bar_policy.envs.term_table import RewardTerm, TerminationTerm

__all__ = ["TaskHooks", "TaskStep", "Transition"]


@dataclass(frozen=True)
class Transition:
    """One control step as the task sees it (a trace-time container, not a pytree)."""

    model: mjx.Model
    """This env's model (possibly randomised)."""
    data: mjx.Data
    """The state after the step; its kinematics (xpos, site_xpos) are the last substep's, 2 ms old."""
    info: dict
    """``State.info`` before the step (the robot's keys included: ``last_act``, ``act_prev`` = the action
    before it, ``step``, ...)."""
    action: jax.Array
    """The clipped action of this step, shape (n,)."""
    tau_sq: jax.Array
    """``sum((tau / tau_cap)^2)`` over joints, averaged over the substeps (dimensionless)."""
    step: jax.Array
    """Control steps since reset, this one included (int32)."""
    finite: jax.Array
    """Whether the new physics state is finite (bool scalar); a non-finite state ends the episode."""
    key: jax.Array
    """PRNG key for the task."""
    near_cap: jax.Array
    """``sum_j clip(|tau_law_j| / tau_cap_j - NEAR_CAP_FRACTION, 0, 1)`` of the unclipped MIT torque,
    averaged over the substeps (dimensionless, <= n): 0 while every joint asks under 80 % of its cap, and it
    keeps growing past the cap where the firmware clips, up to 1.8 caps (``robot.NEAR_CAP_FRACTION``)."""


@dataclass(frozen=True)
class TaskStep:
    """What a task returns from ``task_step`` (a trace-time container, not a pytree)."""

    signals: dict[str, jax.Array]
    """The task's quantities of this step by name (distances, the reference's errors, the keys down...),
    which its term tables read beside the robot's (``LiteRobotEnv.robot_signals``)."""
    info: dict[str, jax.Array]
    """The task's info entries for the new state (merged over the old info)."""
    metrics: dict[str, jax.Array]
    """The task's metrics, scalars (keys = ``metric_keys``)."""


class TaskHooks(abc.ABC):
    """The hooks ``LiteRobotEnv`` calls (see the module docstring)."""

    @abc.abstractmethod
    def task_reset(self, model: mjx.Model, key: jax.Array) -> tuple[dict, jax.Array, jax.Array]:
        """A new episode's task state: ``(task info, initial pose (n,) rad, initial velocity (n,) rad/s)``.

        The robot env adds U(-init_noise, init_noise) to the pose and clips it to the joint limits.
        """

    @abc.abstractmethod
    def task_step(self, tr: Transition) -> TaskStep:
        """The task's signals, metrics and next task info after one control step."""

    @abc.abstractmethod
    def reward_terms(self) -> tuple[RewardTerm, ...]:
        """The task's reward table for the env's current config (weights: ``config.reward.scales``).

        Built on every call from ``self.config``, so an env whose config holds traced weights
        (``reward_weights.with_weights``) gets them in its rows.
        """

    def termination_terms(self) -> tuple[TerminationTerm, ...]:
        """The task's terminations besides the robot's non-finite state (default: none)."""
        return ()

    @abc.abstractmethod
    def task_obs(self, model: mjx.Model, data: mjx.Data, q_meas: jax.Array, info: dict) -> dict:
        """The task's observation inputs (term name -> array).

        From the measured (noisy) joint positions ``q_meas`` (n,) and the new state's ``info``.
        """

    @property
    @abc.abstractmethod
    def metric_keys(self) -> tuple[str, ...]:
        """The task's metric names (besides ``reward/<term>``)."""
