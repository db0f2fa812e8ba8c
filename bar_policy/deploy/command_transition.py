"""Moved to ``bar_policy.tasks.reach.transition``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.reach.transition import *  # noqa: F403
from bar_policy.tasks.reach.transition import __all__  # noqa: F401
