"""Moved to ``bar_policy.tasks.track.config``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.track.config import *  # noqa: F403
from bar_policy.tasks.track.config import __all__  # noqa: F401
