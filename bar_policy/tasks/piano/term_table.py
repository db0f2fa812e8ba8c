"""The piano's reward and termination terms: one table (rows of ``envs.term_table``), summed by the robot env.

Every row reads the step's signals: the robot's (``LiteRobotEnv.robot_signals``: ``q``, ``dq``, ``action``,
...) and the piano's (``LitePiano.task_step``), for the goal row ``t`` of the step: ``key_depression``
(fraction of travel each key is down, (n_keys,)), ``keys_down`` (past the press threshold, bool (n_keys,)),
``goal_keys`` (0/1 (n_keys,)), ``black_goal_keys`` (its black keys, 0/1 (n_keys,)), ``fingertips`` (m, (2,
3)), ``key_sites`` (the keys' top sites, m, (n_keys, 3)), ``hand_goal`` (each hand's next goal keys, bool (2,
n_keys)), ``tau_applied`` (the motor torque the last substep applied, N m, (n,)) and
``reference_action`` (the key-pose reference's filtered action after the step, (n,)). The key terms are the
piano's own (``rewards``, after RoboPianist), the robot's costs ``bar_policy.envs.rewards``'. The weights are
the config's ``reward.scales`` (``RewardScales``, here: what each is and why; the programs' runtime argument).
The piano ends an episode only on the robot's non-finite state: it has no termination of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bar_policy.envs import rewards as robot_rewards
from bar_policy.envs.term_table import RewardTerm, TerminationTerm
from bar_policy.tasks.piano import rewards

__all__ = ["TERMINATIONS", "RewardConfig", "RewardScales", "reward_terms"]


@dataclass(frozen=True, kw_only=True)
class RewardScales:
    """Weights of the reward terms (positive: reward, negative: cost), per step. 0 drops a term."""

    key_press: float = 1.0
    """Goal keys pressed (``rewards.goal_keys_pressed``: mean over the goal keys of a kernel on how far each
    is from the bottom of its travel; RoboPianist's 0.5 x, here with the whole key weight)."""
    key_press_black: float = 0.0
    """Black goal keys pressed, on top of ``key_press`` (``rewards.goal_keys_pressed`` over the black goal
    keys only: 0 at a step without one), so a black goal key pressed earns ``key_press + key_press_black``
    where a white one earns ``key_press``. 0 (the default) leaves the table as it was; the ``piano`` preset
    sets 1.0: the key-pose prior alone presses black keys (held-out black recall 0.884) and files trained
    without it unlearn them (0.494), with the physics, reach and torques alike for both colours
    (docs/piano.md, "Black keys")."""
    wrong_keys: float = -0.5
    """Keys down that are not goal keys (``rewards.wrong_keys_pressed``: their count)."""
    wrong_keys_black_goal: float = 0.0
    """Wrong keys at a step whose goal holds a black key (``rewards.wrong_keys_at_black_goal``), on top of
    ``wrong_keys``: a wrong key there costs ``wrong_keys + wrong_keys_black_goal``. 0 (the default) leaves
    the table as it was; a positive weight relieves the trade a residual learns against the prior's black
    presses, which brush more neighbours than white ones (docs/piano.md, "Black keys")."""
    prior_deviation_black: float = 0.0
    """``sum((a - a_ref)^2)`` of the applied action against the key-pose reference's, at steps whose goal
    holds a black key (``rewards.deviation_at_black_goal``), action units squared. 0 (the default) leaves
    the table as it was; a negative weight keeps a residual on the prior's black presses."""
    prior_deviation_rest: float = 0.0
    """``sum((a - a_ref)^2)`` at steps where neither hand has a goal key in view (the count-in, long rests;
    ``rewards.deviation_at_rest``), action units squared. 0 (the default) leaves the table as it was; a
    negative weight pulls the residual toward the prior where the runtime's tare reads the hand load."""
    fingertip_near: float = 0.5
    """Each hand's fingertip near its next goal key (``rewards.fingertip_to_goal``: 1 within 1 cm)."""
    energy: float = -2e-3
    """Mechanical power ``sum |tau dq|``, W, at the step's end (``tau``: the motor torque the last substep
    applied, without the share of Kd that the implicit damping integrates)."""
    action_rate: float = -0.1
    """``sum((a_t - a_{t-1})^2)`` of the applied action (the tracker's and reach's)."""
    action_accel: float = -0.2
    """``sum((a_t - 2 a_{t-1} + a_{t-2})^2)`` of the applied action: chatter's own penalty."""
    torque_near_cap: float = -0.1
    """``sum_j clip(|tau_law_j| / tau_cap_j - 0.8, 0, 1)`` averaged over substeps."""
    joint_limit: float = -1.0
    """rad beyond the soft joint limits, summed over joints."""


@dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """Reward shaping."""

    scales: RewardScales = field(default_factory=RewardScales)
    """Term weights."""
    soft_limit_fraction: float = 0.95
    """Fraction of each joint's range inside which the joint-limit cost is zero."""


def reward_terms(rc: RewardConfig) -> tuple[RewardTerm, ...]:
    """The piano's reward table of the config's ``reward``: name, function, weight, inputs, parameters.

    The weights are ``rc.scales`` (floats, or traced scalars in a program that takes them as an argument).
    """
    w = rc.scales
    return (
        RewardTerm("key_press", rewards.goal_keys_pressed, w.key_press, ("key_depression", "goal_keys")),
        RewardTerm(
            "key_press_black",
            rewards.goal_keys_pressed,
            w.key_press_black,
            ("key_depression", "black_goal_keys"),
        ),
        RewardTerm("wrong_keys", rewards.wrong_keys_pressed, w.wrong_keys, ("keys_down", "goal_keys")),
        RewardTerm(
            "wrong_keys_black_goal",
            rewards.wrong_keys_at_black_goal,
            w.wrong_keys_black_goal,
            ("keys_down", "goal_keys", "black_goal_keys"),
        ),
        RewardTerm(
            "prior_deviation_black",
            rewards.deviation_at_black_goal,
            w.prior_deviation_black,
            ("action", "reference_action", "black_goal_keys"),
        ),
        RewardTerm(
            "prior_deviation_rest",
            rewards.deviation_at_rest,
            w.prior_deviation_rest,
            ("action", "reference_action", "hand_goal"),
        ),
        RewardTerm(
            "fingertip_near",
            rewards.fingertip_to_goal,
            w.fingertip_near,
            ("fingertips", "key_sites", "hand_goal"),
        ),
        RewardTerm("energy", rewards.energy, w.energy, ("tau_applied", "dq")),
        RewardTerm("action_rate", robot_rewards.action_rate, w.action_rate, ("action", "last_action")),
        RewardTerm(
            "action_accel",
            robot_rewards.action_accel,
            w.action_accel,
            ("action", "last_action", "last_last_action"),
        ),
        RewardTerm("torque_near_cap", robot_rewards.torque_near_cap, w.torque_near_cap, ("near_cap",)),
        RewardTerm(
            "joint_limit",
            robot_rewards.joint_limit,
            w.joint_limit,
            ("q", "q_lower", "q_upper"),
            {"soft_fraction": rc.soft_limit_fraction},
        ),
    )


TERMINATIONS: tuple[TerminationTerm, ...] = ()
"""The piano's terminations besides the robot's non-finite state: none."""
