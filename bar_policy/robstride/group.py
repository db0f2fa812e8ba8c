"""Several ``RobstrideBus`` objects (one per CAN interface) as one flat joint list, plus the safety sequence.

Concurrency: a round sends every bus's frames first, then collects every bus's replies against each bus's
own deadline, so the buses' wire times overlap (interleaved non-blocking send / receive in one thread: no
locks, no thread hand-offs on the control path). The flat joint list is the robot's canonical order.

Safety sequence (``activate``): scan every bus and refuse unless exactly the expected ids answer; check
each motor's model is plausible (``activation.verify_models``) and that its firmware knows the CAN
watchdog (``watchdog.read_can_timeouts``); read the joints with stop frames (the motors stay disabled) and
refuse faults or positions outside the limits (a calibration or 2*pi wrap error); write the torque/current
caps and arm the watchdog (``watchdog.arm_can_timeout``); enable; hold damping at the present pose.
A ``StartupControl`` (``startup``) runs through it: the caller's stop request is checked before every
step (and before each motor's writes), so a stop during start-up ends it with ``StopRequestedError`` and
nothing enabled; a missing reply (scan, parameter exchange, joint read, enable, first damping round) is
retried ``retries`` times with a doubling backoff before activation refuses, and the retries are counted.
The joint read also refuses a motor at or above its over-temperature fault threshold (``temperature``).
``damping_then_stop`` is the one way out: damping frames on every bus, then stop frames on every bus,
whatever fails in between. While running, ``exchange_mit`` refuses replies from motors that left run mode
(``DisabledError``, e.g. the watchdog tripped because the host fell silent for longer than canTimeout).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping, Sequence

import can
import numpy as np

from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride import protocol as proto
from bar_policy.robstride.activation import verify_models, verify_scan, write_caps
from bar_policy.robstride.bus import RobstrideBus
from bar_policy.robstride.bus_types import DEFAULT_REPLY_TIMEOUT, BusReading, MotorConfig
from bar_policy.robstride.calibration import Calibration
from bar_policy.robstride.errors import (
    CommandError,
    DisabledError,
    FaultError,
    InitializationError,
    RobstrideError,
    TimeoutError,
    UnexpectedDeviceError,
)
from bar_policy.robstride.startup import StartupControl
from bar_policy.robstride.temperature import TemperatureMonitor
from bar_policy.robstride.watchdog import arm_can_timeout, read_can_timeouts

__all__ = ["RobstrideGroup"]

log = logging.getLogger(__name__)

_PRECEDENCE = (UnexpectedDeviceError, FaultError, TimeoutError)


class RobstrideGroup:
    """The robot's motors over one ``RobstrideBus`` per CAN interface, in canonical joint order."""

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
        self.startup: StartupControl | None = None
        """The latest ``activate``'s control: its ``retries_used`` say how many retries it needed."""

    @classmethod
    def from_robot(
        cls,
        robot: RobotSpec,
        can_buses: Mapping[str, can.BusABC],
        *,
        calibration: Calibration | None = None,
        reply_timeout: float = DEFAULT_REPLY_TIMEOUT,
        can_timeout: float = proto.DEFAULT_CAN_TIMEOUT,
    ) -> RobstrideGroup:
        """Build from the robot data: one ``RobstrideBus`` per ``can_interface`` (keys of ``can_buses``).

        ``can_timeout`` (s) is every motor's CAN watchdog, armed by ``activate``; 0 leaves the motors' own.
        """
        offsets = (calibration or Calibration.zeros(robot)).offsets(robot)
        buses = []
        for iface in dict.fromkeys(j.can_interface for j in robot.joints):
            if iface not in can_buses:
                raise InitializationError(
                    f"no CAN bus given for interface {iface!r}; given: {sorted(can_buses)}"
                )
            motors = [
                MotorConfig(
                    name=j.name,
                    can_id=j.can_id,
                    model=j.model,
                    direction=j.direction,
                    homing_offset=float(offsets[j.index]),
                    torque_limit=j.torque_limit,
                    current_limit=j.current_limit,
                    can_timeout=can_timeout,
                )
                for j in robot.joints
                if j.can_interface == iface
            ]
            buses.append(RobstrideBus(can_buses[iface], motors, interface=iface, reply_timeout=reply_timeout))
        return cls(buses, robot.joint_names)

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

    # ----------------------------------------------------------------------------------------------
    # activation
    def scan_and_verify(
        self,
        ids: Iterable[int] = range(1, 128),
        *,
        timeout: float = 0.05,
        control: StartupControl | None = None,
    ) -> dict[str, dict[int, bytes]]:
        """Scan every bus; ``InitializationError`` unless exactly the expected ids answer on each.

        With ``control``, expected ids that did not answer are scanned again (``control.attempt``) before
        the mismatch is refused; unknown devices are refused at once.
        """
        ids = list(ids)
        found: dict[str, dict[int, bytes]] = {}
        tries: dict[str, str] = {}
        for bus in self.buses:
            got = found[bus.interface] = {}

            def once(bus: RobstrideBus = bus, got: dict[int, bytes] = got) -> None:
                missing = [i for i in bus.ids if i not in got]
                got.update(bus.scan(missing if got else ids, timeout=timeout))
                still = [i for i in bus.ids if i not in got]
                if still and not set(got) - set(bus.ids):
                    raise TimeoutError(
                        f"{bus.interface}: no reply to the scan within {timeout * 1e3:.0f} ms from "
                        f"{[(i, bus.name_of(i)) for i in still]}",
                        missing=still,
                        interface=bus.interface,
                    )

            if control is None:
                once()
                continue
            try:
                control.attempt(f"scan of {bus.interface}", once)
            except TimeoutError:
                tries[bus.interface] = f" (after {control.retries + 1} scans)"
        problems = []
        for bus in self.buses:
            try:
                verify_scan(bus, found[bus.interface])
            except InitializationError as exc:
                problems.append(f"{exc}{tries.get(bus.interface, '')}")
        if problems:
            raise InitializationError("; ".join(problems))
        for bus in self.buses:
            log.info("%s: scan found exactly the expected ids %s", bus.interface, list(found[bus.interface]))
        return {k: dict(sorted(v.items())) for k, v in found.items()}

    def activate(
        self,
        *,
        lower: np.ndarray,
        upper: np.ndarray,
        scan_ids: Iterable[int] = range(1, 128),
        limit_margin: float = 0.3,
        dry_run: bool = False,
        damping_kd: float = 1.0,
        scan_timeout: float = 0.05,
        control: StartupControl | None = None,
    ) -> BusReading:
        """The safety sequence up to enabling (module docstring). Returns the reading after enabling.

        With ``dry_run`` it stops after the checks (nothing written, nothing enabled). On any failure after
        the first enable frame it sends damping then stop frames before raising. ``control`` (default: a
        ``StartupControl()``, no stop request, the default retries) is kept in ``startup``.

        Raises:
            StopRequestedError: ``control.stop_requested()`` turned true; nothing more was written, and
                nothing was enabled unless the request came after the enable frames (then damped, stopped).
            InitializationError, RobstrideError: a check failed or a reply stayed missing after the retries.
        """
        ctl = control if control is not None else StartupControl()
        self.startup = ctl
        for bus in self.buses:
            bus.retry = ctl
        try:
            return self._activate(
                ctl, lower, upper, scan_ids, limit_margin, dry_run, damping_kd, scan_timeout
            )
        finally:
            for bus in self.buses:
                bus.retry = None
            if ctl.retries_used:
                log.warning(
                    "activation needed %d retries of a missing reply: %s", ctl.total_retries, ctl.retries_used
                )

    def _activate(
        self,
        ctl: StartupControl,
        lower: np.ndarray,
        upper: np.ndarray,
        scan_ids: Iterable[int],
        limit_margin: float,
        dry_run: bool,
        damping_kd: float,
        scan_timeout: float,
    ) -> BusReading:
        ctl.check_stop("the scan")
        self.scan_and_verify(scan_ids, timeout=scan_timeout, control=ctl)
        for bus in self.buses:
            ctl.check_stop(f"the model check on {bus.interface}")
            verify_models(bus)
            ctl.check_stop(f"the canTimeout read on {bus.interface}")
            read_can_timeouts(bus)  # old firmware without canTimeout is refused before anything is written
        ctl.check_stop("the joint read")
        reading = ctl.attempt("joint read", lambda: self.poll_disabled(strict=True))
        hot = self.temperature.check(reading.temperature)
        if hot:
            raise InitializationError("motors too hot to enable: " + "; ".join(hot))
        bad = [
            f"{n}: q={q:+.3f} rad outside [{lo - limit_margin:+.3f}, {hi + limit_margin:+.3f}]"
            for n, q, lo, hi in zip(self.joint_names, reading.q, lower, upper, strict=True)
            if not lo - limit_margin <= q <= hi + limit_margin
        ]
        if bad:
            raise InitializationError(
                "joint positions outside their limits before enabling (calibration file wrong, or the "
                "motor's multi-turn count wrapped by 2*pi at power-on): " + "; ".join(bad)
            )
        if dry_run:
            log.info("dry run: checks passed, nothing written or enabled")
            return reading
        for bus in self.buses:
            write_caps(bus, check_stop=ctl.check_stop)
            ctl.check_stop(f"arming canTimeout on {bus.interface}")
            arm_can_timeout(bus)
        ctl.check_stop("enable")
        try:
            ctl.enabled = True  # from here a failure damps and stops
            enabled = ctl.attempt("enable", self.enable)
            not_run = [n for n, m in zip(self.joint_names, enabled.mode, strict=True) if m != 2]
            if not_run:
                raise InitializationError(f"motors did not enter run mode (mode 2) after enable: {not_run}")
            ctl.check_stop("the damping hold")
            return ctl.attempt(
                "damping hold", lambda: self.exchange_mit(MitCommand.damping(reading.q, damping_kd))
            )
        except BaseException:
            self.damping_then_stop(reading.q, damping_kd, hold_s=0.0)
            raise

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
