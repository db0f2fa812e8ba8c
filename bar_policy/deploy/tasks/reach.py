"""Moved to ``bar_policy.tasks.reach.deploy``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.reach.deploy import *  # noqa: F403
from bar_policy.tasks.reach.deploy import __all__  # noqa: F401
