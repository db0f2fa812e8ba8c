"""``StartupControl``: what one activation's steps share (the stop request, the retry of a missing reply).

The caller's stop request is checked between every step (``check_stop``: after a request nothing more is
written and nothing is enabled), and a missing reply is retried (``attempt``; parameter exchanges through
``RobstrideBus.retry``): ``retries`` more tries after ``backoff``, ``2 * backoff``, ... s, counted in
``retries_used`` per step. ``RobstrideGroup.activate`` runs the sequence (``group``) with the checks of
``activation``; this module sits below both and below ``bus``, which holds the control while activation runs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from bar_policy.robstride.errors import StopRequestedError, TimeoutError

__all__ = ["DEFAULT_RETRIES", "DEFAULT_RETRY_BACKOFF", "StartupControl"]

# Stop requests and retries log on the bus's logger, as they did when activation was part of the bus:
# operators' and tests' log filters select ``bar_policy.robstride.bus``.
log = logging.getLogger("bar_policy.robstride.bus")
_T = TypeVar("_T")

DEFAULT_RETRIES = 3
"""Further tries of an activation exchange whose reply is missing, before activation refuses."""
DEFAULT_RETRY_BACKOFF = 0.02
"""Pause before the first retry, s; it doubles before each further one (20, 40, 80 ms)."""


@dataclass(kw_only=True)
class StartupControl:
    """Stop checks and missing-reply retries of one activation (module docstring).

    Only a missing reply (``TimeoutError``) is retried: a fault, an unknown sender or a refused parameter
    is an answer, and activation refuses on it at once. Before each retry the stop request is checked.
    """

    retries: int = DEFAULT_RETRIES
    """Further tries after a missing reply (0: refuse on the first); per exchange, not per activation."""
    backoff: float = DEFAULT_RETRY_BACKOFF
    """Pause before the first retry of an exchange, s; doubled before each further retry."""
    stop_requested: Callable[[], bool] | None = None
    """The caller's stop request (e.g. ``lambda: stop.requested``); None: never."""
    retries_used: dict[str, int] = field(default_factory=dict)
    """Step -> retries that step needed (steps that needed none are absent)."""
    enabled: bool = False
    """Set once enable frames went out (a stop request after it reports that the motors were stopped)."""

    def __post_init__(self) -> None:
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {self.retries!r}")
        if not self.backoff >= 0:
            raise ValueError(f"backoff must be >= 0 s, got {self.backoff!r}")

    @property
    def total_retries(self) -> int:
        """Retries the whole activation needed."""
        return sum(self.retries_used.values())

    def check_stop(self, step: str) -> None:
        """Raise ``StopRequestedError`` naming ``step`` (the step that would run next) on a stop request."""
        if self.stop_requested is None or not self.stop_requested():
            return
        what = "the motors were enabled: damping, then stop frames" if self.enabled else "nothing was enabled"
        log.warning("stop requested during activation, before %s: %s", step, what)
        raise StopRequestedError(
            f"stop requested during start-up, before {step}: {what}", step=step, enabled=self.enabled
        )

    def attempt(self, step: str, fn: Callable[[], _T]) -> _T:
        """``fn()``, tried again up to ``retries`` times while it raises ``TimeoutError`` (a missing reply).

        Raises:
            TimeoutError: still missing after ``retries + 1`` tries; the message says how many.
            StopRequestedError: a stop was requested before a retry.
        """
        for k in range(self.retries + 1):
            try:
                return fn()
            except TimeoutError as exc:
                if k == self.retries:
                    raise TimeoutError(
                        f"{exc}; refusing after {k + 1} tries ({self.retries} retries, backoff from "
                        f"{self.backoff * 1e3:.0f} ms)",
                        missing=exc.missing,
                        interface=exc.interface,
                    ) from exc
                pause = self.backoff * 2**k
                self.retries_used[step] = self.retries_used.get(step, 0) + 1
                log.warning(
                    "%s: missing reply (%s); retry %d of %d in %.0f ms",
                    step,
                    exc,
                    k + 1,
                    self.retries,
                    pause * 1e3,
                )
                time.sleep(pause)
                self.check_stop(f"retry {k + 1} of {step}")
        raise AssertionError("unreachable")  # pragma: no cover
