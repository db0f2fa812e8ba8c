"""The motors' CAN watchdog ``canTimeout`` (0x7028): arming it at activation, and a bench probe.

What the reference gives (robstride-protocol.md sections 5.2-5.3), and the design that follows from it:

- ``canTimeout`` is a u32 in 50 us ticks ("20000 = 1 s"); 0 = off, the power-on default unless someone saved
  another value. When it is non-zero and no CAN frame reaches the motor for the window, the motor enters
  *reset mode*: disabled, no torque (type-2 mode bits 0).
- Type-18 writes are volatile: they last until the next power cycle. The persistent twin 0x200C changes only
  with a type-22 save, which this driver never sends.
- So activation writes it (``arm_can_timeout``, default 0.2 s = 4000 ticks, 0 skips the write like the caps)
  and stop does **not** restore it: on a motor that was just stopped (reset mode) an armed watchdog changes
  nothing, a power cycle brings back the saved value anyway, and leaving it armed keeps the next program
  that enables the motor covered. Restoring would add a parameter exchange after the stop frames, the one
  part of the stop path that must stay short. ``bar-bus param write --index 0x7028 --value 0`` disarms it.
- Old firmware may not know indexes from 0x7026 up: ``read_can_timeouts`` (run before anything is written,
  in a dry run too) turns a refused read into an ``InitializationError`` that says how to go on.

Unverified on hardware (docs/can.md section 8): the units (kscalelabs labels the twin in microseconds),
whether any frame or only frames addressed to the motor feed the watchdog, and whether a tripped motor is
free or braked by its unpowered anti-back-drive damping (0x702A). ``probe_watchdog`` (``bar-bus watchdog``)
measures the first on one motor.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.robstride import protocol as proto
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.errors import InitializationError, OperationError, RobstrideError

__all__ = ["ProbeResult", "arm_can_timeout", "probe_watchdog", "read_can_timeouts", "verdict"]

log = logging.getLogger(__name__)

_OLD_FIRMWARE = (
    "firmware without canTimeout (0x7028; indexes from 0x7026 are missing on older firmware)? Update the "
    "firmware, or pass --can-timeout 0 to run without the motor-side watchdog (a dead host then leaves the "
    "motors on their last command)"
)


def read_can_timeouts(bus: RobstrideBus) -> dict[int, int]:
    """Read canTimeout (ticks) of every motor whose ``can_timeout`` is non-zero; read-only.

    Raises:
        InitializationError: a motor refuses or ignores the read (old firmware), naming it and the way out.
    """
    out: dict[int, int] = {}
    for m in bus.motors:
        if m.can_timeout == 0:
            continue
        try:
            out[m.can_id] = int(bus.read_param(m.can_id, proto.PARAM_CAN_TIMEOUT))
        except RobstrideError as exc:
            raise InitializationError(
                f"{bus.interface}: cannot read canTimeout of {m.name} (id {m.can_id}): {exc}; "
                + _OLD_FIRMWARE
            ) from exc
        log.info(
            "%s: canTimeout of can_id=%d (%s) is %d ticks (%g s) before arming",
            bus.interface,
            m.can_id,
            m.name,
            out[m.can_id],
            out[m.can_id] * proto.CAN_TIMEOUT_TICK,
        )
    return out


def arm_can_timeout(bus: RobstrideBus, *, verify: bool = True) -> list[tuple[int, int]]:
    """Write every motor's ``can_timeout`` to canTimeout (type 18, u32 ticks); 0 skips the write.

    Logs every write and skip; reads each write back when ``verify``. Returns (id, ticks) written.

    Raises:
        InitializationError: a write is not acknowledged or reads back different (names motor and values).
    """
    written = []
    for m in bus.motors:
        if m.can_timeout == 0:
            log.info(
                "skipped canTimeout (0) for can_id=%d (%s) on %s: the motor keeps its own watchdog setting",
                m.can_id,
                m.name,
                bus.interface,
            )
            continue
        ticks = proto.can_timeout_ticks(m.can_timeout)
        try:
            bus.write_param(m.can_id, proto.PARAM_CAN_TIMEOUT, ticks)
            back = int(bus.read_param(m.can_id, proto.PARAM_CAN_TIMEOUT)) if verify else ticks
        except RobstrideError as exc:
            raise InitializationError(
                f"{bus.interface}: cannot write canTimeout={ticks} to {m.name} (id {m.can_id}): {exc}; "
                + _OLD_FIRMWARE
            ) from exc
        if back != ticks:
            raise InitializationError(
                f"{bus.interface}: wrote canTimeout={ticks} ticks to {m.name} (id {m.can_id}) but it reads "
                f"back {back}"
            )
        log.info(
            "wrote canTimeout=%d ticks (%g s) to can_id=%d (%s) on %s",
            ticks,
            ticks * proto.CAN_TIMEOUT_TICK,
            m.can_id,
            m.name,
            bus.interface,
        )
        written.append((m.can_id, ticks))
    return written


# ---------------------------------------------------------------------------------------------------
# bench probe (bar-bus watchdog)
# ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class ProbeResult:
    """One silence of the probe."""

    silence: float
    """Measured time between the last frame to the motor and the probing frame, s."""
    mode: int
    """Mode in the reply to the probing frame: 2 = still running, 0 = reset (tripped), -1 = no reply."""


def _sleep_until(t: float, stop: Callable[[], bool]) -> bool:
    """Sleep until ``perf_counter() >= t`` in <= 10 ms slices; False when ``stop()`` became true."""
    while (left := t - time.perf_counter()) > 0:
        if stop():
            return False
        time.sleep(min(left, 0.01))
    return True


def probe_watchdog(
    bus: RobstrideBus,
    silences: Sequence[float],
    *,
    keepalive_s: float = 0.1,
    period: float = 0.02,
    timeout: float = 0.05,
    stop: Callable[[], bool] = lambda: False,
) -> list[ProbeResult]:
    """Measure whether the motor of ``bus`` (exactly one) trips after each silence; leaves it disabled.

    Per silence: enable (type 3), zero-torque MIT frames (Kp = Kd = 0, tau = 0: the shaft is free) every
    ``period`` for ``keepalive_s``, then nothing for the silence, then one zero-torque frame whose reply
    reports the mode (2 still running, 0 tripped), then a stop frame. The watchdog must already be armed
    (``arm_can_timeout``). Returns early, with the results so far, when ``stop()`` becomes true.

    Raises:
        OperationError: the motor does not answer, or does not enter run mode after the enable frame.
    """
    if len(bus.motors) != 1:
        raise ValueError(f"probe_watchdog needs a bus with exactly one motor, got {len(bus.motors)}")
    can_id = bus.ids[0]
    zero = bus.mit_frames(*np.zeros((5, 1)))[0]

    def feedback(frame: proto.Frame) -> proto.Feedback:
        reply = bus.request(frame, lambda r: isinstance(r, proto.Feedback) and r.motor_id == can_id, timeout)
        assert isinstance(reply, proto.Feedback)  # guaranteed by the match
        return reply

    results: list[ProbeResult] = []
    for silence in silences:
        if stop():
            break
        fb = feedback(proto.enable_frame(can_id, bus.host_id))
        if fb.mode != 2:
            mode_name = proto.MODE_NAMES[fb.mode]
            raise OperationError(f"id {can_id} reports mode {mode_name} after enable, not run")
        end = time.perf_counter() + keepalive_s
        while True:
            last = time.perf_counter()
            feedback(zero)
            if last + period >= end or not _sleep_until(last + period, stop):
                break
        if not _sleep_until(last + silence, stop):
            break
        t = time.perf_counter()
        try:
            mode = feedback(zero).mode
        except RobstrideError:
            mode = -1
        results.append(ProbeResult(silence=t - last, mode=mode))
        feedback(proto.stop_frame(can_id, host_id=bus.host_id))
        log.info("silence %.3f s -> mode %s", t - last, proto.MODE_NAMES.get(mode, "no reply"))
    return results


def verdict(results: Sequence[ProbeResult], expected: float) -> tuple[bool, str]:
    """Whether the probe agrees with a watchdog of ``expected`` s, and a one-line explanation."""
    ran = [r.silence for r in results if r.mode == 2]
    tripped = [r.silence for r in results if r.mode == 0]
    if not ran and not tripped:
        return False, "no usable replies"
    if not tripped:
        return False, (
            f"never tripped, up to {max(ran):.3f} s of silence: the firmware ignores canTimeout, or its "
            f"window is longer than {expected:g} s (different units?)"
        )
    if not ran:
        return False, (
            f"tripped after every silence, even {min(tripped):.3f} s: the window is shorter than "
            f"{expected:g} s (microsecond units?)"
        )
    lo, hi = max(ran), min(tripped)
    if lo >= hi:
        return False, f"inconsistent: ran after {lo:.3f} s but tripped after {hi:.3f} s of silence"
    ok = lo < expected <= hi
    ticks, tick_us = proto.can_timeout_ticks(expected), proto.CAN_TIMEOUT_TICK * 1e6
    return ok, (
        f"trips between {lo:.3f} and {hi:.3f} s of silence: "
        + ("consistent with" if ok else "NOT consistent with")
        + f" {expected:g} s = {ticks} ticks of {tick_us:g} us"
    )
