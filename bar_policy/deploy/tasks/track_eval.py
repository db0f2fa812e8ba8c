"""Moved to ``bar_policy.tasks.track.evaluate``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.track.evaluate import *  # noqa: F403
from bar_policy.tasks.track.evaluate import __all__  # noqa: F401
