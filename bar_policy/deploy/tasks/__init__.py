"""Deploy-side tasks: one module per task builds its command source, its evaluation and its CLI options.

The runtime loop never names a task: it feeds the observation's state terms itself (``deploy.inputs``) and
takes the command terms, the HOLD pose before the policy and the end of the commands from a
``CommandSource`` (``tasks.base``). Which task a policy file runs is read from its metadata
(``OnnxPolicy.task``): ``bar.task`` for ``bar`` files; for HC-only files the task its terms imply
(``implied_task``), as HC's ``task_type`` is a free label.

========  ======================================  =========================  ==============================
task      module                                  command source (CLI)       ``bar-deploy eval`` metric
========  ======================================  =========================  ==============================
reach     ``tasks.reach``                         ``--commands SPEC``        segment success rate
track     ``tasks.track`` (+ ``track_eval``)      ``--motion NAME|PATH``     joint / body / fingertip error
state     ``tasks.state``                         none (HC-only, state only) none
========  ======================================  =========================  ==============================

This module is light (no task module is imported until ``get_task``): ``deploy.hc_policy`` reads the
command terms below while a policy loads.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bar_policy.deploy.tasks.base import DeployTask

__all__ = ["HC_TASKS", "TASKS", "TASK_COMMAND_TERMS", "all_tasks", "get_task", "implied_task"]

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


def get_task(name: str) -> DeployTask:
    """The deploy task called ``name`` (imports its module).

    Raises:
        ValueError: an unknown name; the message lists the tasks.
    """
    if name not in TASKS:
        raise ValueError(f"this runtime has no deploy task {name!r}; tasks: {sorted(TASKS)}")
    return importlib.import_module(TASKS[name]).TASK


def all_tasks() -> tuple[DeployTask, ...]:
    """Every deploy task, in ``TASKS`` order."""
    return tuple(get_task(name) for name in TASKS)
