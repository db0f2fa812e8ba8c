"""The tasks: one folder per task (``reach/``, ``track/``), each registered once in ``registry.py``.

A task's folder holds its shared definition, the observation terms and layout it adds, its MJX env, its
training presets and its deploy part, and its ``RECORD`` (``record.TaskRecord``), which the env registry,
the observation layouts, the training presets and ``bar-deploy`` read (``docs/tasks.md``). This package
and each task's ``__init__`` import no jax (deploy imports them with jax blocked). It names no task and
imports nothing: the registry is ``bar_policy.tasks.registry``.
"""

__all__: list[str] = []
