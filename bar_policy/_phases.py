"""Named wall-clock phases that code below ``training`` can mark, for the trainer's start-up breakdown.

The env marks its model build (``with phase("model build"): ...``); the trainer holds a ``PhaseClock`` and
activates it while it builds the env, so those seconds get their own row instead of hiding inside "env
construction". Without an active clock ``phase`` costs one global read. Standard library only (the
deploy side imports nothing from here, but could).

Phases are *exclusive*: the seconds of a phase opened inside another are taken out of the outer one, so
the phases of one clock never overlap and add up to at most the wall time around them. Only the thread
that created the clock records (worker threads, such as the compile threads, are ignored: their time
overlaps the main thread's).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

__all__ = ["MODEL_BUILD", "PhaseClock", "phase"]

MODEL_BUILD = "model build (MJCF compile, mjx.put_model)"
"""The env's phase: compiling the MJCF with C MuJoCo and putting model and data on the device."""


class PhaseClock:
    """Exclusive seconds per named phase, measured on the thread that created the clock."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        """Phase -> exclusive seconds (insertion order is the order phases first ended)."""
        self._thread = threading.get_ident()
        self._children: list[float] = []
        """Seconds already attributed to nested phases, one entry per open phase."""

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time the block as ``name``, less the phases nested inside it; other threads record nothing."""
        if threading.get_ident() != self._thread:
            yield
            return
        t0 = time.monotonic()
        self._children.append(0.0)
        try:
            yield
        finally:
            nested = self._children.pop()
            dt = time.monotonic() - t0
            self.seconds[name] = self.seconds.get(name, 0.0) + max(0.0, dt - nested)
            if self._children:
                self._children[-1] += dt

    def add(self, name: str, seconds: float) -> None:
        """Record ``seconds`` measured elsewhere on this thread as ``name`` (taken out of an open phase)."""
        if threading.get_ident() != self._thread:
            return
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds
        if self._children:
            self._children[-1] += seconds

    @contextlib.contextmanager
    def active(self) -> Iterator[PhaseClock]:
        """Make this the clock that module-level ``phase`` records into, for the block."""
        global _ACTIVE
        previous, _ACTIVE = _ACTIVE, self
        try:
            yield self
        finally:
            _ACTIVE = previous


_ACTIVE: PhaseClock | None = None


@contextlib.contextmanager
def phase(name: str) -> Iterator[None]:
    """Time the block as ``name`` on the active ``PhaseClock`` (``PhaseClock.active``), if there is one."""
    clock = _ACTIVE
    if clock is None:
        yield
        return
    with clock.phase(name):
        yield
