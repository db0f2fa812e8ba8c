"""Moved to ``bar_policy.tasks.cli_types``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.cli_types import *  # noqa: F403
from bar_policy.tasks.cli_types import __all__  # noqa: F401
