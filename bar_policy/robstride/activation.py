"""Activation-time checks and configuration of one ``RobstrideBus``: run once before enabling, never per tick.

``RobstrideGroup.activate`` runs them per bus (group.py holds the order of the safety sequence; the CAN
watchdog's read and write are in ``watchdog``): ``verify_scan`` refuses a bus unless exactly its motor ids
answered the scan, ``verify_models`` refuses a motor whose torque cap 0x700B (N*m) exceeds its configured
model's T_max, ``write_caps`` writes the torque (0x700B, N*m) and current (0x7018, A) caps (type 18,
volatile) and reads them back. All failures raise ``InitializationError`` naming the interface, joint and id.
Functions over the bus (it owns the I/O) rather than methods, so ``bus.py`` stays the control path.

What the whole sequence shares (the caller's stop request, the retry of a missing reply) is
``startup.StartupControl``. Imports point one way: ``activation`` -> ``bus`` -> ``startup``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from bar_policy.robot.actuators import robstride_spec
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.errors import InitializationError, RobstrideError
from bar_policy.robstride.framing import PARAM_LIMIT_CURRENT, PARAM_LIMIT_TORQUE

__all__ = ["verify_models", "verify_scan", "write_caps"]

# The cap writes and skips log on the bus's logger, as they did when they were bus methods: operators' and
# tests' log filters select ``bar_policy.robstride.bus``.
log = logging.getLogger("bar_policy.robstride.bus")


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
