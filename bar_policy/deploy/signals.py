"""What ``bar-deploy`` does with a SIGINT that arrives before its stop path is installed.

The stop path itself (SIGINT, SIGTERM and SIGHUP -> one flag: ``StopSignals``) is ``bar_policy.signals``,
shared with ``bar-bus``. Before ``StopSignals`` is installed (the first fraction of a second of
``bar-deploy``: imports, argument parsing, loading the policy and the commands) Python's own SIGINT handler
raises ``KeyboardInterrupt``; ``bar-deploy``'s ``main`` catches it and ends quietly, without a traceback
(``early_interrupt``): for a run, as a stop before the start (``SIGINT received before the start: nothing
was started``, status 0, the same as a signal that arrives after the handlers but before the start); for
``eval`` and ``plot``, which have no stop path, with one line on stderr and ``INTERRUPT_STATUS`` (130, the
shell's 128 + SIGINT).
"""

from __future__ import annotations

import signal

__all__ = ["INTERRUPT_STATUS", "early_interrupt"]

INTERRUPT_STATUS = 128 + signal.SIGINT
"""Exit status of a ``bar-deploy eval`` / ``plot`` ended by SIGINT (130, the shell's convention)."""


def early_interrupt(command: str) -> tuple[int, str]:
    """The exit status and the one line (no traceback) for a SIGINT that came as ``KeyboardInterrupt``.

    ``run``: nothing was started, so it is a stop before the start (status 0, a line for stdout, as when
    the signal comes after ``StopSignals`` but before the start). Any other subcommand (``eval``, ``plot``):
    ``INTERRUPT_STATUS`` and ``bar-deploy <command>: interrupted (SIGINT)`` for stderr. The CLI prints it.
    """
    if command == "run":
        return 0, "SIGINT received before the start: nothing was started"
    return INTERRUPT_STATUS, f"bar-deploy {command}: interrupted (SIGINT)"
