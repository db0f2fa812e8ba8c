"""One stop path for every way an operator or a supervisor asks the process to end.

SIGINT (Ctrl+C in a terminal), SIGTERM (``kill``, systemd, ``docker stop``) and SIGHUP (the SSH session or
terminal went away) all mean "stop now, safely". ``StopSignals`` turns each of them into the same flag,
which the control loop (and ``bar-bus calibrate``) polls once per tick and answers with DAMPING, then stop
frames on every bus, then the log. The handler never raises: a second signal while the stop sequence
runs is counted and logged, and cannot cut the stop frames short. SIGKILL cannot be caught; on the real
robot the motors' CAN watchdog (``canTimeout``) then ends the last command (docs/can.md).

While a ``StopSignals`` context is entered, long loads of user files (songs, clips) call ``check_stop``
between chunks: a stop asked for while ``bar-deploy`` reads them ends the load within one chunk
(``StopRequested``, a ``KeyboardInterrupt``) instead of after the whole file.

Handlers can only be installed from the main thread; elsewhere ``StopSignals`` installs nothing and the
flag can still be set with ``request`` (tests, embedding code).

Shared by ``bar-deploy`` (``bar_policy.deploy``) and ``bar-bus`` (``bar_policy.robstride``), so it lives
below both; what ``bar-deploy`` does with a SIGINT that comes before ``StopSignals`` is installed is in
``bar_policy.deploy.signals``.
"""

from __future__ import annotations

import logging
import signal
import threading
from types import FrameType
from typing import Any

__all__ = ["STOP_SIGNALS", "StopRequested", "StopSignals", "check_stop"]

log = logging.getLogger(__name__)

STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Signals that request a safe stop."""


class StopRequested(KeyboardInterrupt):
    """A stop request met by a long load (``check_stop``): the load ends where it is, nothing was started.

    A ``KeyboardInterrupt``, so it unwinds like the SIGINT that usually causes it and ``bar-deploy`` ends
    as for any stop before the start (status 0, no traceback).
    """


_ACTIVE: list[StopSignals] = []
"""The ``StopSignals`` contexts entered and not yet left, innermost last."""


def check_stop(what: str) -> None:
    """Raise ``StopRequested`` when an entered ``StopSignals`` has a stop request; else return at once.

    Loaders of user files (song, clip, CSV) call it between chunks, so a stop asked for during a long load
    acts within one chunk's time instead of after the whole load. ``what``: the load, for the message.
    """
    for stop in _ACTIVE:
        if stop.requested:
            raise StopRequested(f"{stop.reason}: {what} interrupted")


class StopSignals:
    """Context manager: SIGINT, SIGTERM and SIGHUP set ``requested`` (the first one names the reason).

    Usage::

        with StopSignals() as stop:
            while not stop.requested:
                tick()
        # stop.reason == "SIGTERM received" (for example), stop.count == signals seen
    """

    def __init__(self, signals: tuple[signal.Signals, ...] = STOP_SIGNALS) -> None:
        self.signals = tuple(signals)
        self.requested = False
        """True once a stop signal (or ``request``) arrived."""
        self.signal_name: str | None = None
        """Name of the first signal, e.g. ``SIGTERM``; None before any (or after ``request``)."""
        self.reason = ""
        """Why the stop was requested (first request wins)."""
        self.count = 0
        """Stop signals received (the later ones are ignored)."""
        self._previous: dict[signal.Signals, Any] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for s in self.signals:
                self._previous[s] = signal.signal(s, self._handle)
        _ACTIVE.append(self)  # ``check_stop`` sees its requests
        return self

    def __exit__(self, *exc: object) -> None:
        for s, previous in self._previous.items():
            signal.signal(s, previous)
        self._previous.clear()
        if self in _ACTIVE:
            _ACTIVE.remove(self)

    @property
    def installed(self) -> bool:
        """Whether the handlers are installed (False outside the main thread)."""
        return bool(self._previous)

    def request(self, reason: str) -> None:
        """Ask for a stop without a signal (the first request's reason is kept)."""
        if not self.requested:
            self.requested = True
            self.reason = reason

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        self.count += 1
        if not self.requested:
            self.signal_name = name
            self.request(f"{name} received")
            log.warning("%s received: stopping (DAMPING, then stop frames, then the log)", name)
        else:
            log.warning(
                "%s received again (%d signals): ignored, the stop sequence finishes first "
                "(SIGKILL would skip it; the motors' CAN watchdog then stops them)",
                name,
                self.count,
            )
