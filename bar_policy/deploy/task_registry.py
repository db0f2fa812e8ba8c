"""The deploy tasks by name: the module of each, the command terms each feeds, an HC-only file's task.

Light (imports no task module): ``deploy.policy`` and ``deploy.hc_policy`` read it while a policy loads, below
the task modules, which take a policy. ``deploy.tasks`` re-exports it and imports a task's module on demand.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = ["HC_TASKS", "TASKS", "TASK_COMMAND_TERMS", "implied_task"]

TASKS: dict[str, str] = {
    "reach": "bar_policy.deploy.tasks.reach",
    "track": "bar_policy.deploy.tasks.track",
    "state": "bar_policy.deploy.tasks.state",
}
"""Deploy task name -> the module that defines it (its ``TASK``)."""

TASK_COMMAND_TERMS: dict[str, tuple[str, ...]] = {
    "reach": ("target_pos_left", "target_pos_right"),
    "track": ("motion_joint_pos", "motion_body_pos_b", "motion_body_ori_b"),
    "state": (),
}
"""The command terms each task's source can feed (``tests/deploy`` checks them against the modules)."""

HC_TASKS = ("reach", "state")
"""Tasks an HC-only file may have (``deploy.hc_policy``: tracking terms are not fed to HC-only files)."""

_REACH_STATE_TERMS = ("fingertip_pos_left", "fingertip_pos_right")


def implied_task(observation_names: Sequence[str]) -> str:
    """The deploy task of an HC-only file from its observation terms.

    ``reach`` when it reads a reach target or a fingertip, ``track`` when it reads a reference term, else
    ``state`` (the robot's own state only).
    """
    names = set(observation_names)
    if names & {*TASK_COMMAND_TERMS["reach"], *_REACH_STATE_TERMS}:
        return "reach"
    if names & set(TASK_COMMAND_TERMS["track"]):
        return "track"
    return "state"
