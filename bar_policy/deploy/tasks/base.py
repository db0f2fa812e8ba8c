"""Moved to ``bar_policy.tasks.interfaces``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.interfaces import *  # noqa: F403
from bar_policy.tasks.interfaces import __all__  # noqa: F401
