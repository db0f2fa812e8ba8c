"""Policies that read the robot's state only (HC-only files whose terms are joint_pos, joint_vel, actions).

Such a policy takes no command source: ``NoCommands`` feeds nothing and keeps no schedule, and neither
``--commands`` nor ``--motion`` is accepted. There is no task metric, so ``bar-deploy eval`` refuses it.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

from bar_policy.tasks.interfaces import CommandSource, DeployTask

if TYPE_CHECKING:
    from bar_policy.deploy.policy import OnnxPolicy
    from bar_policy.robot.kinematics import Kinematics

__all__ = ["TASK", "NoCommands", "StateTask"]


class NoCommands(CommandSource):
    """A source with no command terms (state-only policies)."""

    task = "state"

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        """Nothing."""
        return {}

    def describe(self) -> str:
        """One line for logs."""
        return "none (state-only policy)"


class StateTask(DeployTask):
    """``state``: no commands, no evaluation."""

    name = "state"
    summary = "robot state only, no commands"
    usage = "it takes no command source (neither --commands nor --motion)"
    default_duration = 10.0

    def command_source(
        self, policy: OnnxPolicy, args: argparse.Namespace, kinematics: Kinematics | None = None
    ) -> NoCommands:
        """The empty source."""
        return NoCommands()


TASK = StateTask()
"""The ``state`` deploy task."""
