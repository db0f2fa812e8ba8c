"""Moved to ``bar_policy.tasks.track.deploy``; this old path re-exports it (``docs/tasks.md``)."""

from bar_policy.tasks.track.deploy import *  # noqa: F403
from bar_policy.tasks.track.deploy import __all__  # noqa: F401
