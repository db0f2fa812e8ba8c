"""Moved to ``bar_policy.tasks.track.env``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.track.env import *  # noqa: F403
from bar_policy.tasks.track.env import __all__  # noqa: F401
