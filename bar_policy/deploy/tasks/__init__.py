"""Deploy-side tasks: one module per task builds its command source, its evaluation and its CLI options.

The runtime loop never names a task: it feeds the observation's state terms itself (``deploy.inputs``) and
takes the command terms, the HOLD pose before the policy and the end of the commands from a
``CommandSource`` (``bar_policy.tasks.interfaces``). Which task a policy file runs is read from its metadata
(``OnnxPolicy.task``): ``bar.task`` for ``bar`` files; for HC-only files the task its terms imply
(``implied_task``), as HC's ``task_type`` is a free label.

========  =================================  =========================  =================================
task      module                             command source (CLI)       ``bar-deploy eval`` metric
========  =================================  =========================  =================================
reach     ``bar_policy.tasks.reach.deploy``  ``--commands SPEC``        segment success rate
track     ``bar_policy.tasks.track.deploy``  ``--motion NAME|PATH``     joint / body / fingertip error
state     ``deploy.tasks.state``             none (HC-only, state only) none
========  =================================  =========================  =================================

The tasks are those of the registry (``bar_policy.tasks.registry``: each ``TaskRecord.deploy``), plus
``state``. This module is light (no task module is imported until ``get_task``). The names, the command
terms and ``implied_task`` live in ``deploy.task_registry`` (re-exported here), which ``deploy.policy`` and
``deploy.hc_policy`` read while a policy loads.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from bar_policy.deploy.task_registry import HC_TASKS, TASK_COMMAND_TERMS, TASKS, implied_task

if TYPE_CHECKING:
    from bar_policy.tasks.interfaces import DeployTask

__all__ = ["HC_TASKS", "TASKS", "TASK_COMMAND_TERMS", "all_tasks", "get_task", "implied_task"]


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
