"""A stop signal that arrives before ``bar-deploy`` installs its stop path: no traceback, a documented status.

Standard library only, so the console entry point (``bar_policy.entry``) can import it before numpy and
the rest of the package: until ``StopSignals`` (``bar_policy.signals``) is installed, SIGINT is Python's
``KeyboardInterrupt`` and SIGTERM / SIGHUP would end the process silently with status -15 / -1.
``install`` makes SIGTERM and SIGHUP raise ``EarlyStop`` (a ``KeyboardInterrupt``) as well, and
``early_interrupt`` turns the interrupt into one line and an exit status:

- ``run``: nothing was started, so it is a stop before the start (status 0, a line for stdout, as when the
  signal comes after ``StopSignals`` but before the start);
- any other subcommand (``eval``, ``plot``, ``log``), which have no stop path: ``INTERRUPT_STATUS`` (130,
  the shell's 128 + SIGINT) and ``bar-deploy <command>: interrupted (SIG...)`` for stderr.

What is left: a signal during the interpreter's own start-up, before the entry point's first line runs
(the remaining window is measured in docs/deploy.md).
"""

from __future__ import annotations

import signal

__all__ = ["INTERRUPT_STATUS", "EarlyStop", "early_interrupt", "install", "signal_name_of"]

INTERRUPT_STATUS = 128 + signal.SIGINT
"""Exit status of ``bar-deploy eval`` / ``plot`` / ``log`` ended by a signal (130, the shell's convention)."""


class EarlyStop(KeyboardInterrupt):
    """SIGTERM or SIGHUP before the stop path is installed (``install``); ``signame`` names it."""

    def __init__(self, signame: str) -> None:
        super().__init__(signame)
        self.signame = signame


def _raise_early(signum: int, frame: object) -> None:
    raise EarlyStop(signal.Signals(signum).name)


def install() -> None:
    """SIGTERM and SIGHUP raise ``EarlyStop`` (main thread only) until ``StopSignals`` takes them over."""
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _raise_early)


def signal_name_of(exc: KeyboardInterrupt) -> str:
    """The signal behind an interrupt: ``EarlyStop``'s, else SIGINT (Python's own ``KeyboardInterrupt``)."""
    return exc.signame if isinstance(exc, EarlyStop) else "SIGINT"


def early_interrupt(command: str, signame: str = "SIGINT") -> tuple[int, str]:
    """The exit status and the one line (no traceback) for a stop signal that came as ``KeyboardInterrupt``.

    ``run``: status 0 and a line for stdout; any other subcommand: ``INTERRUPT_STATUS`` and a line for
    stderr (module docstring). The caller prints it.
    """
    if command == "run":
        return 0, f"{signame} received before the start: nothing was started"
    return INTERRUPT_STATUS, f"bar-deploy {command}: interrupted ({signame})"
