"""``RobstrideGroup``: the robot's buses as one flat joint list (``rounds``), plus the safety sequence.

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
Rounds, the MIT exchange and the way out (``damping_then_stop``) are ``rounds.GroupRounds``.
"""

from __future__ import annotations

import logging
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
from bar_policy.robstride.errors import InitializationError, TimeoutError
from bar_policy.robstride.rounds import GroupRounds
from bar_policy.robstride.startup import StartupControl
from bar_policy.robstride.watchdog import arm_can_timeout, read_can_timeouts

__all__ = ["RobstrideGroup"]

log = logging.getLogger(__name__)


class RobstrideGroup(GroupRounds):
    """The robot's motors over one ``RobstrideBus`` per CAN interface, in canonical joint order.

    Rounds, ``exchange_mit``, ``damping_then_stop`` and ``stop`` come from ``GroupRounds`` (``rounds``).
    """

    def __init__(self, buses: Sequence[RobstrideBus], joint_names: Sequence[str]) -> None:
        super().__init__(buses, joint_names)
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
