"""Activation-time checks and configuration of one ``RobstrideBus``: run once before enabling, never per tick.

``RobstrideGroup.activate`` runs them per bus (group.py holds the order of the safety sequence; the CAN
watchdog's read and write are in ``watchdog``): ``verify_scan`` refuses a bus unless exactly its motor ids
answered the scan, ``verify_models`` refuses a motor whose torque cap 0x700B (N*m) exceeds its configured
model's T_max, ``write_caps`` writes the torque (0x700B, N*m) and current (0x7018, A) caps (type 18,
volatile) and reads them back. All failures raise ``InitializationError`` naming the interface, joint and id.
Functions over the bus (it owns the I/O) rather than methods, so ``bus.py`` stays the control path.
``RobstrideBus.write_caps`` delegates here.

``StartupControl`` carries what the whole sequence shares: the caller's stop request, checked between
every step (``check_stop``: after a request nothing more is written and nothing is enabled), and the retry
of a missing reply (``attempt``; parameter exchanges through ``RobstrideBus.retry``): ``retries`` more tries
after ``backoff``, ``2 * backoff``, ... s, counted in ``retries_used`` per step.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, TypeVar

from bar_policy.robot.actuators import robstride_spec
from bar_policy.robstride.errors import (
    InitializationError,
    RobstrideError,
    StopRequestedError,
    TimeoutError,
)
from bar_policy.robstride.framing import PARAM_LIMIT_CURRENT, PARAM_LIMIT_TORQUE

if TYPE_CHECKING:  # bus.py imports this module (for the ``write_caps`` method): no import cycle at run time
    from bar_policy.robstride.bus import RobstrideBus

__all__ = [
    "DEFAULT_RETRIES",
    "DEFAULT_RETRY_BACKOFF",
    "StartupControl",
    "verify_models",
    "verify_scan",
    "write_caps",
]

# The cap writes and skips log on the bus's logger, as they did when they were bus methods: operators' and
# tests' log filters select ``bar_policy.robstride.bus``.
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
                    "%s: missing reply (%s); retry %d of %d in %.0f ms", step, exc, k + 1, self.retries,
                    pause * 1e3,
                )  # fmt: skip
                time.sleep(pause)
                self.check_stop(f"retry {k + 1} of {step}")
        raise AssertionError("unreachable")  # pragma: no cover


def verify_scan(bus: RobstrideBus, found: Iterable[int]) -> None:
    """Refuse (``InitializationError``) unless exactly this bus's motor ids answered the scan."""
    found_set, expected = set(found), set(bus.ids)
    missing, extra = sorted(expected - found_set), sorted(found_set - expected)
    if missing or extra:
        raise InitializationError(
            f"{bus.interface}: scan mismatch, refusing to enable. expected ids {sorted(expected)}; "
            f"missing {[(i, bus.name_of(i)) for i in missing]}; unknown devices {extra}"
        )


def verify_models(bus: RobstrideBus, *, tolerance: float = 1e-3) -> dict[int, float]:
    """Check each motor's model is plausible; returns id -> limit_torque read.

    There is no documented model-id parameter, so the model comes from the robot data and is checked
    against the torque cap 0x700B: its power-on default is the model's T_max and the firmware keeps it
    within [0, T_max], so a value above the configured model's T_max proves a bigger model than
    configured (e.g. an rs-02 where an rs-05 belongs). A smaller model than configured can pass
    (its cap reads like a lowered cap): the hardware check list in docs/can.md covers that.
    """
    read: dict[int, float] = {}
    for m in bus.motors:
        try:
            value = float(bus.read_param(m.can_id, PARAM_LIMIT_TORQUE))
        except RobstrideError as exc:
            raise InitializationError(
                f"{bus.interface}: cannot read limit_torque of {m.name} (id {m.can_id}): {exc}"
            ) from exc
        t_max = robstride_spec(m.model).t_max
        if not 0.0 <= value <= t_max + tolerance:
            raise InitializationError(
                f"{bus.interface}: {m.name} (id {m.can_id}) reports limit_torque={value:g} N*m, outside "
                f"[0, {t_max:g}] of the configured {m.model}: wrong model on this id, refusing to enable"
            )
        read[m.can_id] = value
    return read


def write_caps(
    bus: RobstrideBus, *, verify: bool = True, check_stop: Callable[[str], None] | None = None
) -> list[tuple[int, str, float]]:
    """Write the torque (0x700B) and current (0x7018) caps of every motor; a cap of 0 is skipped.

    Logs every write and skip; reads each write back when ``verify``. Returns (id, param, value) written.
    ``check_stop(step)`` runs before each motor's writes (``StartupControl.check_stop``).
    """
    written = []
    for m in bus.motors:
        if check_stop is not None:
            check_stop(f"the cap writes of {m.name} on {bus.interface}")
        for index, pname, value in (
            (PARAM_LIMIT_TORQUE, "torque_limit", m.torque_limit),
            (PARAM_LIMIT_CURRENT, "current_limit", m.current_limit),
        ):
            if value == 0:
                log.info(
                    "skipped %s (cap 0) for can_id=%d (%s) on %s", pname, m.can_id, m.name, bus.interface
                )
                continue
            bus.write_param(m.can_id, index, value)
            if verify:
                back = float(bus.read_param(m.can_id, index))
                if abs(back - value) > 1e-4 * max(1.0, abs(value)):
                    raise InitializationError(
                        f"{bus.interface}: wrote {pname}={value:g} to {m.name} (id {m.can_id}) "
                        f"but it reads back {back:g}"
                    )
            log.info(
                "wrote %s=%s to can_id=%d (%s) on %s",
                pname,
                float(value),
                m.can_id,
                m.name,
                bus.interface,
            )
            written.append((m.can_id, pname, float(value)))
    return written
