"""Moved to ``bar_policy.tasks.reach.commands``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.reach.commands import *  # noqa: F403
from bar_policy.tasks.reach.commands import __all__  # noqa: F401
