"""bar_policy: a JAX-vectorised learned-policy runtime for the Lite humanoid, with an MJX training env."""

from bar_policy import task_records as _task_records

__version__ = "0.1.0"

__all__ = ["__version__"]


def _load_tasks() -> None:
    """Import the task registry, which publishes every task's record (``task_records.records``)."""
    import bar_policy.tasks.registry  # noqa: F401


_task_records.install_loader(_load_tasks)
