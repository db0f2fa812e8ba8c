"""Moved to ``bar_policy.tasks.track.reference``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.track.reference import *  # noqa: F403
from bar_policy.tasks.track.reference import __all__  # noqa: F401
