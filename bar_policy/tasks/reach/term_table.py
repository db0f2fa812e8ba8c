"""Reach's reward and termination terms: one table (rows of ``envs.term_table``), summed by the robot env.

Every row reads the step's signals: the robot's (``LiteRobotEnv.robot_signals``: ``action``, ``q``,
``dq``, ``tau_sq``, ...) and reach's (``LiteReach.task_step``): ``dist_left`` and ``dist_right``, each
true fingertip's distance to its commanded target (m), and ``q_wrist`` / ``q_wrist_default``, the wrist
joints and their default pose (rad, (6,)). The weights are the config's ``reward.scales``
(``RewardScales``, here: what each is and why; the programs' runtime argument), the parameters its
``reward`` lengths and fraction (``RewardConfig``). Reach ends an episode only on the robot's non-finite
state: it has no termination of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bar_policy.envs import rewards
from bar_policy.envs.term_table import RewardTerm, TerminationTerm
from bar_policy.tasks.reach.shared import SUCCESS_RADIUS

__all__ = ["TERMINATIONS", "RewardConfig", "RewardScales", "reward_terms"]


@dataclass(frozen=True, kw_only=True)
class RewardScales:
    """Weights of the reward terms (positive: reward, negative: cost). 0 drops a term's effect."""

    reach_coarse: float = 1.0
    """Weight of ``1 - tanh(d / coarse_std)`` (mean of both hands), per step."""
    reach_fine: float = 1.0
    """Weight of ``1 - tanh(d / fine_std)`` (mean of both hands), per step."""
    success: float = 0.5
    """Weight of the both-hands-within-3-cm indicator, per step."""
    action_rate: float = -0.1
    """Weight of ``sum((a_t - a_{t-1})^2)`` of the applied action, per step (action units); the tracker's
    (BeyondMimic's) -0.1; -0.01 shipped a policy at its torque caps 6 % of the time with 34 mrad of
    chatter (docs/training.md)."""
    action_accel: float = -0.2
    """Weight of ``sum((a_t - 2 a_{t-1} + a_{t-2})^2)`` of the applied action, per step: chatter's own
    penalty, as the tracker's."""
    joint_limit: float = -1.0
    """Weight of rad beyond the soft joint limits (summed over joints), per step."""
    torque: float = -0.005
    """Weight of ``sum((tau / tau_cap)^2)`` averaged over substeps, per step."""
    torque_near_cap: float = -0.1
    """Weight of ``sum_j clip(|tau_law_j| / tau_cap_j - 0.8, 0, 1)`` of the unclipped MIT demand averaged
    over substeps (``Transition.near_cap``): a new target must be reached without slamming into the caps."""
    joint_vel: float = -5e-4
    """Weight of ``sum(dq^2)`` in (rad/s)^2, per step."""
    wrist_posture: float = -0.1
    """Weight of ``sum_j |q_j - q_default_j|`` over the wrist joints, rad, per step: reach does not need
    the wrists, and a policy that holds them away from the default pose sends its first command of each
    episode toward that posture, which met the 4 N m wrist caps in the ship gate (docs/training.md). At
    -0.1 it cost no env steps to 95 % (three seeds); -0.3 needed 1.6-1.8x as many."""


@dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """Reward shaping."""

    scales: RewardScales = field(default_factory=RewardScales)
    """Term weights."""
    coarse_std: float = 0.15
    """Length scale of the coarse distance kernel, m."""
    fine_std: float = 0.03
    """Length scale of the fine distance kernel, m (the success radius)."""
    soft_limit_fraction: float = 0.95
    """Fraction of each joint's range inside which the joint-limit cost is zero."""

    def __post_init__(self) -> None:
        if not (self.coarse_std > 0 and self.fine_std > 0):
            raise ValueError(f"kernel stds must be > 0 m, got {self.coarse_std}, {self.fine_std}")
        if not 0 < self.soft_limit_fraction <= 1:
            raise ValueError(f"soft_limit_fraction must be in (0, 1], got {self.soft_limit_fraction}")


DISTANCES = ("dist_left", "dist_right")
"""The two fingertip-to-target distances, m (reach's signals)."""


def reward_terms(rc: RewardConfig) -> tuple[RewardTerm, ...]:
    """Reach's reward table of the config's ``reward``: name, function, weight, inputs (signals), parameters.

    The weights are ``rc.scales`` (floats, or traced scalars in a program that takes them as an argument).
    """
    w = rc.scales
    return (
        RewardTerm("reach_coarse", rewards.reach_kernel, w.reach_coarse, DISTANCES, {"std": rc.coarse_std}),
        RewardTerm("reach_fine", rewards.reach_kernel, w.reach_fine, DISTANCES, {"std": rc.fine_std}),
        RewardTerm("success", rewards.success, w.success, DISTANCES, {"radius": SUCCESS_RADIUS}),
        RewardTerm("action_rate", rewards.action_rate, w.action_rate, ("action", "last_action")),
        RewardTerm(
            "action_accel",
            rewards.action_accel,
            w.action_accel,
            ("action", "last_action", "last_last_action"),
        ),
        RewardTerm(
            "joint_limit",
            rewards.joint_limit,
            w.joint_limit,
            ("q", "q_lower", "q_upper"),
            {"soft_fraction": rc.soft_limit_fraction},
        ),
        RewardTerm("torque", rewards.torque, w.torque, ("tau_sq",)),
        RewardTerm("torque_near_cap", rewards.torque_near_cap, w.torque_near_cap, ("near_cap",)),
        RewardTerm("joint_vel", rewards.joint_vel, w.joint_vel, ("dq",)),
        RewardTerm("wrist_posture", rewards.joint_deviation, w.wrist_posture, ("q_wrist", "q_wrist_default")),
    )


TERMINATIONS: tuple[TerminationTerm, ...] = ()
"""Reach's terminations besides the robot's non-finite state: none."""
