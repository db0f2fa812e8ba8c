"""The registration list: one line per task.

Adding a task = a folder under ``bar_policy/tasks/`` with a ``RECORD`` (``record.TaskRecord``) in its
``__init__.py``, plus its line in ``TASK_PACKAGES`` (``docs/tasks.md``).

Importing it loads every task's record and publishes them to ``bar_policy.task_records`` (where the layers
below the tasks read them: the env registry ``bar_policy.envs``, the observation layouts
``ObservationManager.for_task`` and ``SHIPPED_LAYOUTS``), and registers each task's ship gate
(``quality.gate``). The layers above read the records here: the training presets (``training.config.PRESETS``)
and ``bar-deploy``'s task table (``deploy.task_registry``). Reading the records imports each task package's
``__init__`` (its shared numpy definitions) and nothing heavier.
"""

from __future__ import annotations

import importlib

from bar_policy.quality.gate import register_gate
from bar_policy.task_records import EnvEntry, TaskRecord, get_record, publish, resolve

__all__ = ["TASKS", "TASK_PACKAGES", "env_entries", "get_task_record"]

TASK_PACKAGES: tuple[str, ...] = (
    "bar_policy.tasks.reach",
    "bar_policy.tasks.track",
    "bar_policy.tasks.piano",
)
"""The task packages, in registry order (each defines ``RECORD``)."""


def _load(package: str) -> TaskRecord:
    record = getattr(importlib.import_module(package), "RECORD", None)
    if not isinstance(record, TaskRecord):
        raise TypeError(
            f"task package {package} must define RECORD, a TaskRecord; got {type(record).__name__}"
        )
    return record


TASKS: tuple[TaskRecord, ...] = tuple(_load(p) for p in TASK_PACKAGES)
"""Every registered task's record."""

publish(TASKS)  # checks the task and env names are unique
for _r in TASKS:  # each task's ship gate, from its folder, into the one gate table
    if _r.gate:
        register_gate(_r.name, resolve(_r.gate))

get_task_record = get_record
"""The record of task ``name``; raises ``ValueError`` listing the tasks (``task_records.get_record``)."""


def env_entries() -> dict[str, tuple[TaskRecord, EnvEntry]]:
    """Env name -> (its task's record, its entry), in registry order."""
    return {e.name: (r, e) for r in TASKS for e in r.envs}
