"""Several ``RobstrideBus`` objects (one per CAN interface) as one flat joint list: rounds and the way out.

Concurrency: a round sends every bus's frames first, then collects every bus's replies against each bus's
own deadline, so the buses' wire times overlap (interleaved non-blocking send / receive in one thread: no
locks, no thread hand-offs on the control path). The flat joint list is the robot's canonical order.
While running, ``exchange_mit`` refuses replies from motors that left run mode (``DisabledError``, e.g. the
watchdog tripped because the host fell silent for longer than canTimeout). ``damping_then_stop`` is the one
way out: damping frames on every bus, then stop frames on every bus, whatever fails in between.

``RobstrideGroup`` (``group``: construction from the robot data, the safety sequence) inherits all of this
from ``GroupRounds``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np

from bar_policy.robot.mit import MitCommand
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.bus_types import BusReading
from bar_policy.robstride.errors import (
    CommandError,
    DisabledError,
    FaultError,
    RobstrideError,
    TimeoutError,
    UnexpectedDeviceError,
)
from bar_policy.robstride.temperature import TemperatureMonitor

__all__ = ["GroupRounds"]

# The group's logger, as when these methods were defined in group.py: log filters select it by name.
log = logging.getLogger("bar_policy.robstride.group")

_PRECEDENCE = (UnexpectedDeviceError, FaultError, TimeoutError)


class GroupRounds:
    """The robot's motors over one ``RobstrideBus`` per CAN interface, in canonical joint order: rounds."""

    def __init__(self, buses: Sequence[RobstrideBus], joint_names: Sequence[str]) -> None:
        self.buses = tuple(buses)
        self.joint_names = tuple(joint_names)
        where = {m.name: (b, i) for b, bus in enumerate(self.buses) for i, m in enumerate(bus.motors)}
        missing = [n for n in self.joint_names if n not in where]
        extra = sorted(set(where) - set(self.joint_names))
        if missing or extra:
            raise ValueError(f"buses do not cover the joints: missing {missing}, not joints {extra}")
        self._flat = [
            np.array([self.joint_names.index(m.name) for m in bus.motors], dtype=np.int64)
            for bus in self.buses
        ]
        self.last_reading: BusReading | None = None
        """The most recent flat reading (also after a failed round: NaN where replies were missing)."""
        self.last_sent: float | None = None
        """``perf_counter`` when the latest round's frames went out (None before the first round)."""
        models = {m.name: m.model for bus in self.buses for m in bus.motors}
        self.temperature = TemperatureMonitor(self.joint_names, [models[n] for n in self.joint_names])
        """The over-temperature watch of every joint (``check`` it with each reading's temperatures)."""

    @property
    def num_joints(self) -> int:
        """Number of joints."""
        return len(self.joint_names)

    def shutdown(self) -> None:
        """Close every CAN bus (sends nothing)."""
        for bus in self.buses:
            bus.shutdown()

    # ----------------------------------------------------------------------------------------------
    # rounds
    def round(self, frames: Sequence[Sequence[proto.Frame]], *, strict: bool = True) -> BusReading:
        """Send ``frames[b]`` on bus b for every bus, then collect one reply per motor on every bus.

        All buses are collected even when one fails; then the most severe error is raised (unexpected id,
        fault, timeout), with the other buses' errors attached as notes. ``last_reading`` is set first.
        """
        self.last_sent = time.perf_counter()
        deadlines = [bus.send_round(f) for bus, f in zip(self.buses, frames, strict=True)]
        parts: list[BusReading] = []
        errors: list[RobstrideError] = []
        for bus, deadline in zip(self.buses, deadlines, strict=True):
            try:
                parts.append(bus.collect_round(deadline, strict=strict))
            except RobstrideError as exc:
                errors.append(exc)
                parts.append(bus.last_reading)
        reading = self._merge(parts)
        self.last_reading = reading
        if errors:
            errors.sort(key=lambda e: next((k for k, t in enumerate(_PRECEDENCE) if isinstance(e, t)), 9))
            first = errors[0]
            for other in errors[1:]:
                first.add_note(f"also: {other}")
            raise first
        return reading

    def _merge(self, parts: Sequence[BusReading]) -> BusReading:
        n = self.num_joints
        out = {k: np.full(n, np.nan) for k in ("q", "dq", "tau", "temperature")}
        mode = np.full(n, -1, dtype=np.int64)
        faults = np.zeros(n, dtype=np.int64)
        for idx, r in zip(self._flat, parts, strict=True):
            for k, arr in out.items():
                arr[idx] = getattr(r, k)
            mode[idx], faults[idx] = r.mode, r.faults
        return BusReading(**out, mode=mode, faults=faults, stamp=max(p.stamp for p in parts))

    def mit_frames(self, cmd: MitCommand) -> list[list[proto.Frame]]:
        """Per-bus MIT frames of a flat command (fields shape (num_joints,)), joint frame."""
        values = np.empty((5, self.num_joints))
        try:
            for k, f in enumerate(cmd):
                values[k] = f  # broadcasts scalars, checks shapes
        except (ValueError, TypeError) as exc:
            raise CommandError(f"MIT command fields must have shape ({self.num_joints},): {exc}") from exc
        return [bus.mit_frames(*values[:, idx]) for bus, idx in zip(self.buses, self._flat, strict=True)]

    def exchange_mit(self, cmd: MitCommand) -> BusReading:
        """One control tick: one MIT frame per motor out, one reply per motor back (all buses).

        Raises ``DisabledError`` when a motor's reply reports a mode other than run (motors ignore MIT frames
        in reset mode, so an arm would hang limp while the caller believes it is commanded).
        """
        before = self.last_sent
        reading = self.round(self.mit_frames(cmd))
        if (reading.mode != 2).any():
            self._raise_not_running(reading, before)
        return reading

    def _raise_not_running(self, reading: BusReading, before: float | None) -> None:
        off = {self.joint_names[i]: int(reading.mode[i]) for i in np.flatnonzero(reading.mode != 2)}
        names = [f"{n} ({proto.MODE_NAMES.get(mode, mode)})" for n, mode in off.items()]
        motors = [m for bus in self.buses for m in bus.motors]
        watchdog = min((m.can_timeout for m in motors if m.can_timeout > 0), default=0.0)
        gap = self.last_sent - before if before is not None and self.last_sent is not None else None
        why = "something else disabled them (another node on the bus, a brown-out reset)"
        if watchdog and gap is not None and gap >= watchdog:
            why = (
                f"the CAN watchdog tripped: the previous round went out {gap * 1e3:.0f} ms earlier, longer "
                f"than canTimeout {watchdog * 1e3:.0f} ms (the host stalled or started ticking late)"
            )
        elif gap is not None:
            why += f"; the previous round went out {gap * 1e3:.0f} ms earlier"
        raise DisabledError(
            f"motors left run mode while commanded: {', '.join(names)}: {why}",
            can_ids=[m.can_id for m in motors if m.name in off],
            interface=",".join(b.interface for b in self.buses),
        )

    def poll_disabled(self, *, strict: bool = False) -> BusReading:
        """Read every joint with stop (type 4, byte0 = 0) frames: the motors stay / become disabled."""
        return self.round([bus.stop_frames() for bus in self.buses], strict=strict)

    def enable(self) -> BusReading:
        """Enable (type 3) every motor; strict."""
        return self.round([bus.enable_frames() for bus in self.buses])

    def damping_then_stop(self, q: np.ndarray | None = None, kd: float = 1.0, *, hold_s: float = 0.0) -> None:
        """Damping frames (Kp = 0, Kd = ``kd``, q_cmd = ``q``) on every bus, then stop frames on every bus.

        Best effort: errors are logged, never raised, and the stop frames go out whatever happened. The
        damping is repeated for ``hold_s`` seconds (at most every 10 ms) so the arms settle before the stop.
        """
        if q is None:
            q = self.last_reading.q if self.last_reading is not None else np.zeros(self.num_joints)
        q = np.where(np.isfinite(q), q, 0.0)
        try:
            cmd = MitCommand.damping(q, kd)
            end = time.monotonic() + hold_s
            while True:
                try:
                    frames = self.mit_frames(cmd)
                except RobstrideError as exc:
                    log.error("damping frames: %s", exc)
                    break
                self._best_effort_round(frames)
                if time.monotonic() >= end:
                    break
                time.sleep(min(0.01, max(0.0, end - time.monotonic())))
        finally:
            self.stop()

    def _best_effort_round(self, frames: Sequence[Sequence[proto.Frame]]) -> BusReading | None:
        """Send on every bus independently, then collect non-strictly; errors are logged.

        One bus failing to send never keeps the frames off another. None when no bus could send.
        """
        sent: list[tuple[int, float]] = []
        self.last_sent = time.perf_counter()
        for b, (bus, f) in enumerate(zip(self.buses, frames, strict=True)):
            try:
                sent.append((b, bus.send_round(f)))
            except RobstrideError as exc:
                log.error("%s: cannot send: %s", bus.interface, exc)
        if not sent:
            return None
        parts = {b: self.buses[b].collect_round(deadline, strict=False) for b, deadline in sent}
        return self._merge([parts.get(b) or self.buses[b].empty_reading() for b in range(len(self.buses))])

    def stop(self, *, clear_faults: bool = False) -> BusReading | None:
        """Stop (type 4) frames on every bus; best effort (errors logged). Returns the replies' reading."""
        reading = self._best_effort_round([bus.stop_frames(clear_faults=clear_faults) for bus in self.buses])
        if reading is not None:
            missing = [n for n, m in zip(self.joint_names, reading.mode, strict=True) if m < 0]
            if missing:
                log.warning("no reply to the stop frame from %s", missing)
        return reading

    def stop_each(self, *, clear_faults: bool = False) -> np.ndarray:
        """Stop (type 4) frames one motor at a time per bus; which joints answered, bool (num_joints,).

        A joint counts as answered only for a type-2 reply carrying its own CAN id that arrived after its
        own stop frame and before the next motor's frame on that bus (``RobstrideBus.send_stop`` /
        ``await_reply``): a reply from another motor that answers in its place with its id, or a late reply
        to an earlier frame, does not count. The buses run side by side (motor k of every bus, then motor
        k + 1), so a silent motor delays the next stop frame on its bus by one reply deadline at most.
        Best effort: errors are logged, every motor's stop frame is tried.
        """
        index = {name: i for i, name in enumerate(self.joint_names)}
        answered = np.zeros(self.num_joints, dtype=bool)
        for k in range(max((len(bus.motors) for bus in self.buses), default=0)):
            sent: list[tuple[RobstrideBus, int, str, float]] = []
            for bus in self.buses:
                if k >= len(bus.motors):
                    continue
                motor = bus.motors[k]
                try:
                    sent.append(
                        (
                            bus,
                            motor.can_id,
                            motor.name,
                            bus.send_stop(motor.can_id, clear_faults=clear_faults),
                        )
                    )
                except RobstrideError as exc:
                    log.error("%s: cannot send the stop frame of %s: %s", bus.interface, motor.name, exc)
            for bus, can_id, name, deadline in sent:
                try:
                    answered[index[name]] = bus.await_reply(can_id, deadline) is not None
                except RobstrideError as exc:
                    log.error("%s: stop reply of %s: %s", bus.interface, name, exc)
        missing = [n for n, ok in zip(self.joint_names, answered, strict=True) if not ok]
        if missing:
            log.warning("no reply carrying its own id to its stop frame from %s", missing)
        return answered
