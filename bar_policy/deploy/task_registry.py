"""The deploy tasks by name: the module of each, the command terms each feeds, an HC-only file's task.

Read from the task records (``bar_policy.tasks.registry``: each task's ``deploy`` module, ``command_terms``,
``implied_by``, ``hc_only``), plus the runtime's own ``state`` task for HC-only files that read the robot's
state only. Light (imports no deploy task module): ``deploy.policy`` and ``deploy.hc_policy`` read it while a
policy loads, below the task modules, which take a policy. ``deploy.tasks`` re-exports it and imports a
task's module on demand.
"""

from __future__ import annotations

from collections.abc import Sequence

from bar_policy.tasks.registry import TASKS as _RECORDS

__all__ = ["HC_TASKS", "TASKS", "TASK_COMMAND_TERMS", "implied_task"]

_STATE = "state"
"""The runtime's task for policies that read the robot's state only (``deploy.tasks.state``)."""

TASKS: dict[str, str] = {
    **{r.name: r.deploy for r in _RECORDS if r.deploy},
    _STATE: "bar_policy.deploy.tasks.state",
}
"""Deploy task name -> the module that defines it (its ``TASK``)."""

TASK_COMMAND_TERMS: dict[str, tuple[str, ...]] = {
    **{r.name: r.command_terms for r in _RECORDS if r.deploy},
    _STATE: (),
}
"""The command terms each task's source can feed (``tests/deploy`` checks them against the modules)."""

HC_TASKS: tuple[str, ...] = (*(r.name for r in _RECORDS if r.deploy and r.hc_only), _STATE)
"""Tasks an HC-only file may have (``deploy.hc_policy``: tracking terms are not fed to HC-only files)."""


def implied_task(observation_names: Sequence[str]) -> str:
    """The deploy task of an HC-only file from its observation terms.

    The first registered task that one of the terms implies (``TaskRecord.implied_by``: reach when the file
    reads a reach target or a fingertip, track when it reads a reference term), else ``state`` (the robot's
    own state only).
    """
    names = set(observation_names)
    for r in _RECORDS:
        if r.deploy and names & set(r.implied_by):
            return r.name
    return _STATE
