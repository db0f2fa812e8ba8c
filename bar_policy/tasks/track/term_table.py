"""Tracking's reward and termination terms: one table (rows of ``envs.term_table``), summed by the robot env.

Every row reads the step's signals: the robot's (``LiteRobotEnv.robot_signals``: ``q``, ``action``,
``tau_sq``, ...) and tracking's (``LiteTrack.task_step``), all against the reference frame the step arrives
at: ``q_ref`` (rad, (n,)); ``body_pos`` / ``body_pos_ref`` (m, (B, 3)) and ``body_rot`` / ``body_ori_ref``
(rotation matrices (B, 3, 3), 6-D form (B, 6)) of ``TRACK_BODY_NAMES``; ``fingertip_pos`` /
``fingertip_pos_ref`` (m, (2, 3)); ``body_dist``, each tracked body's distance to its reference (m, (B,)).
The weights are the config's ``reward.scales`` (``TrackRewardScales``: what each is and why), the
parameters its ``reward`` kernel widths and its ``termination_distance``.
"""

from __future__ import annotations

from bar_policy.envs import rewards
from bar_policy.envs.term_table import RewardTerm, TerminationTerm
from bar_policy.envs.terminations import farther_than
from bar_policy.tasks.track.config import TrackEnvConfig, TrackRewardConfig

__all__ = ["reward_terms", "termination_terms"]


def reward_terms(rc: TrackRewardConfig) -> tuple[RewardTerm, ...]:
    """Tracking's reward table of the config's ``reward``: name, function, weight, inputs, parameters.

    The weights are ``rc.scales`` (floats, or traced scalars in a program that takes them as an argument).
    """
    w = rc.scales
    return (
        RewardTerm("joint_pos", rewards.joint_tracking, w.joint_pos, ("q", "q_ref"), {"std": rc.joint_std}),
        RewardTerm(
            "body_pos",
            rewards.body_pos_tracking,
            w.body_pos,
            ("body_pos", "body_pos_ref"),
            {"std": rc.body_pos_std},
        ),
        RewardTerm(
            "body_ori",
            rewards.body_ori_tracking,
            w.body_ori,
            ("body_rot", "body_ori_ref"),
            {"std": rc.body_ori_std},
        ),
        RewardTerm(
            "fingertip_pos",
            rewards.body_pos_tracking,
            w.fingertip_pos,
            ("fingertip_pos", "fingertip_pos_ref"),
            {"std": rc.fingertip_std},
        ),
        RewardTerm("action_rate", rewards.action_rate, w.action_rate, ("action", "last_action")),
        RewardTerm(
            "action_accel",
            rewards.action_accel,
            w.action_accel,
            ("action", "last_action", "last_last_action"),
        ),
        RewardTerm("torque", rewards.torque, w.torque, ("tau_sq",)),
        RewardTerm("torque_near_cap", rewards.torque_near_cap, w.torque_near_cap, ("near_cap",)),
    )


def termination_terms(cfg: TrackEnvConfig) -> tuple[TerminationTerm, ...]:
    """Tracking's terminations besides the robot's non-finite state: a tracked body lost.

    ``lost``: any tracked body farther than ``termination_distance`` (m) from its reference (never at 0).
    """
    return (TerminationTerm("lost", farther_than, ("body_dist",), {"limit": cfg.termination_distance}),)
