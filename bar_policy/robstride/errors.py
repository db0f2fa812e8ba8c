"""Typed errors of the Robstride driver (style.md item 16).

``RobstrideError`` is the root; every failure the driver raises on purpose is one of its subclasses, so a
caller can catch the whole family, or one kind:

- ``InitializationError``: the bus or the motors cannot be brought up (wrong scan, bad calibration file,
  unreadable parameter). Nothing was enabled.
- ``BusOpenError`` (an ``InitializationError``): the CAN interface cannot be opened or used: no SocketCAN in
  the kernel, the interface is absent, or it is down. The one-line message says how to fix it.
- ``OperationError``: a running exchange failed (unexpected sender, invalid command, send error).
- ``DisabledError`` (an ``OperationError``): a motor that should be running reports reset mode (disabled):
  its CAN watchdog ``canTimeout`` tripped, or something else stopped it.
- ``TimeoutError``: replies missing at the deadline; also a ``builtins.TimeoutError``.
- ``FaultError``: a motor reported fault bits (type-2 status bits or a type-21 fault frame).
- ``FrameError``: a CAN frame is not a valid Robstride frame of the expected direction; also a ``ValueError``.
- ``StopRequestedError``: a stop was requested (SIGINT, SIGTERM, SIGHUP) during activation; the sequence
  ended at the next step. Nothing was enabled when it came before the enable frames; otherwise the motors
  were damped and stopped before it was raised.
"""

from __future__ import annotations

import builtins
from collections.abc import Mapping, Sequence

from bar_policy._files import InputError

__all__ = [
    "BusOpenError",
    "CommandError",
    "DisabledError",
    "FaultError",
    "FrameError",
    "InitializationError",
    "OperationError",
    "RobstrideError",
    "StopRequestedError",
    "TimeoutError",
    "UnexpectedDeviceError",
]


class RobstrideError(Exception):
    """Root of every error the Robstride driver raises deliberately."""


class InitializationError(RobstrideError):
    """The bus or its motors cannot be brought up; nothing was enabled."""


class BusOpenError(InitializationError):
    """A CAN interface cannot be opened or used (SocketCAN missing, interface absent or down)."""

    def __init__(self, message: str, *, interface: str = "", channel: str = "") -> None:
        super().__init__(message)
        self.interface = interface
        """The python-can interface (``socketcan``, ``virtual``)."""
        self.channel = channel
        """The channel (``can0``)."""


class OperationError(RobstrideError):
    """An exchange with running motors failed."""


class DisabledError(OperationError):
    """Motors that should be running report reset mode (disabled), e.g. after a watchdog trip."""

    def __init__(self, message: str, *, can_ids: Sequence[int], interface: str = "") -> None:
        super().__init__(message)
        self.can_ids = tuple(can_ids)
        """The CAN ids that left run mode."""
        self.interface = interface
        """The CAN interface names, comma separated."""


class CommandError(OperationError, ValueError):
    """A command is invalid (non-finite field, wrong shape); nothing was sent."""


class UnexpectedDeviceError(OperationError):
    """A reply came from a CAN id that is not one of this bus's motors."""

    def __init__(self, message: str, *, can_ids: Sequence[int], interface: str) -> None:
        super().__init__(message)
        self.can_ids = tuple(can_ids)
        """The unexpected sender ids."""
        self.interface = interface
        """The CAN interface name."""


class TimeoutError(RobstrideError, builtins.TimeoutError):
    """Replies were missing when the deadline passed."""

    def __init__(self, message: str, *, missing: Sequence[int] = (), interface: str = "") -> None:
        super().__init__(message)
        self.missing = tuple(missing)
        """CAN ids that did not answer."""
        self.interface = interface
        """The CAN interface name."""


class FaultError(RobstrideError):
    """One or more motors reported fault bits."""

    def __init__(
        self,
        message: str,
        *,
        faults: Mapping[int, int],
        fault_words: Mapping[int, int] | None = None,
        interface: str = "",
    ) -> None:
        super().__init__(message)
        self.faults = dict(faults)
        """CAN id -> type-2 fault bits (id bits 21..16 as a 6-bit number)."""
        self.fault_words = dict(fault_words or {})
        """CAN id -> type-21 fault word."""
        self.interface = interface
        """The CAN interface name."""


class FrameError(RobstrideError, InputError):
    """A CAN frame is not a valid Robstride frame (wrong id format, length, type or direction)."""


class StopRequestedError(RobstrideError):
    """A stop was requested during activation; the sequence ended at the next step (module docstring)."""

    def __init__(self, message: str, *, step: str, enabled: bool = False) -> None:
        super().__init__(message)
        self.step = step
        """The start-up step that did not run (``enable``, ``write caps on can0``, ...)."""
        self.enabled = enabled
        """Whether enable frames had gone out before the request was seen (the motors were then damped and
        stopped)."""
