"""The real target: the Lite's Robstride actuators in MIT mode over CAN (python-can), one bus per arm.

``RealTarget`` is asynchronous (wall clock): ``advance`` only returns, the runtime keeps the rate.

- ``start()`` runs the safety sequence of ``RobstrideGroup.activate``: scan (exactly the expected ids),
  model plausibility, canTimeout support, joint positions within limits, cap writes, the CAN watchdog
  (``canTimeout``, default 0.2 s: a motor that hears no frame for that long disables itself, so a killed
  host cannot leave the arms on their last command), enable, damping hold at the present pose. The caller
  must then tick (``read_state``/``write_command``) at least every ``can_timeout`` s, from the first tick on.
  With ``dry_run`` it stops before writing anything; reads then poll with stop frames and commands are
  encoded, decoded and logged, never sent.
- ``write_command`` is one round on both buses (one MIT frame per motor, one reply each). ``read_state``
  returns fresh feedback: it re-sends the last command (harmless: the motors already apply it) unless
  ``refresh_on_read`` is off (the lockstep emulator, whose replies already carry the post-step state).
- Any driver error (missing reply, fault bit, unexpected id, invalid command, a motor that left run mode:
  a watchdog trip), ``KeyboardInterrupt`` or other exception inside a read or write runs the safe stop
  (``safe_stop``: damping for ``damping_hold_s``, then stop frames on every bus), then raises
  (``TargetError`` from the driver error). ``close()`` does the same when the motors are still enabled.
  The safe stop runs once: a later ``safe_stop`` (the runtime's safe ending after that error) sends nothing
  and returns the first one's ``StopReport``, so a run's CAN log holds exactly one damping-then-stop.
- The damping frames of the safe stop carry ``tau_ff`` from ``use_stop_torque`` (the runtime's
  gravity compensation at the measured q, ``deploy.gravity``) when one is set, else 0.
- ``record_can(path)`` records the raw traffic of every bus to a BLF (or ASC) file until ``close()``
  (``robstride.can_record``; ``bar-deploy`` writes ``run.blf`` in the run directory).

The CLI glue (``add_arguments``, ``make_target``) is ``targets.real_cli``; ``targets.real`` re-exports both.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import NoReturn, TypeVar

import numpy as np

from bar_policy.deploy.targets.base import JointState, StopReport, Target, TargetError
from bar_policy.robot.constants import RobotSpec
from bar_policy.robot.mit import MitCommand
from bar_policy.robstride.bus_types import BusReading
from bar_policy.robstride.can_record import CanRecorder
from bar_policy.robstride.errors import (
    CommandError,
    RobstrideError,
    StopRequestedError,
)
from bar_policy.robstride.framing import fault_names
from bar_policy.robstride.group import RobstrideGroup
from bar_policy.robstride.motor_side import decode_request
from bar_policy.robstride.startup import DEFAULT_RETRIES, DEFAULT_RETRY_BACKOFF, StartupControl

__all__ = ["RealTarget"]

log = logging.getLogger("bar_policy.deploy.targets.real")  # the real target's logger, as before the split
_T = TypeVar("_T")


class RealTarget(Target):
    """The robot's Robstride motors as a ``Target`` (canonical joint order, joint frame)."""

    synchronous = False

    def __init__(
        self,
        robot: RobotSpec,
        group: RobstrideGroup,
        *,
        dry_run: bool = False,
        refresh_on_read: bool = True,
        damping_kd: float = 1.0,
        damping_hold_s: float = 0.2,
        scan_ids: Iterable[int] = range(1, 128),
        limit_margin: float = 0.3,
        companions: Sequence[object] = (),
        stop_requested: Callable[[], bool] | None = None,
        activation_retries: int = DEFAULT_RETRIES,
        retry_backoff: float = DEFAULT_RETRY_BACKOFF,
    ) -> None:
        super().__init__(robot.joint_names)
        if group.joint_names != robot.joint_names:
            raise ValueError("the bus group's joint order differs from the robot's canonical order")
        self.robot = robot
        self.group = group
        self.dry_run = dry_run
        self.applies_commands = not dry_run  # a dry run sends no command: the arms never follow one
        self.refresh_on_read = refresh_on_read
        self.damping_kd = damping_kd
        self.damping_hold_s = damping_hold_s
        self.scan_ids = list(scan_ids)
        self.limit_margin = limit_margin
        self.companions = list(companions)
        """Objects with ``close()`` closed after the buses (the in-process emulator)."""
        self.stop_requested = stop_requested
        """The caller's stop request, checked between every start-up step (``start``); None: never."""
        self.activation_retries = activation_retries
        """Further tries of a start-up exchange whose reply is missing, before activation refuses."""
        self.retry_backoff = retry_backoff
        """Pause before the first such retry, s; doubled before each further one."""
        self.startup: StartupControl | None = None
        """The latest ``start``'s control (``retries_used``: step -> retries of a missing reply it needed)."""
        self.enabled = False
        """True between a successful enable and the stop frames."""
        self.stopped = False
        """True once damping-then-stop ran; commands are refused afterwards."""
        self.stop_report: StopReport | None = None
        """The safe stop's report (None before it ran); a later ``safe_stop`` returns it unchanged."""
        self._stop_torque: Callable[[np.ndarray], np.ndarray] | None = None
        self._last_cmd: MitCommand | None = None
        self._reading: BusReading | None = None
        self._closed = False
        self.can_recorder: CanRecorder | None = None
        """The raw CAN log of every bus (``record_can``); closed by ``close()``."""

    def record_can(self, path: str | Path) -> Path:
        """Record the raw traffic of every bus to ``path`` (``.blf`` or ``.asc``) until ``close()``.

        ``bar-deploy`` calls it with ``<run dir>/run.blf`` before ``start()``, so the file holds the whole
        exchange: scan, parameter writes, enable, every control round, the damping and stop frames.
        """
        if self.can_recorder is not None:
            raise RuntimeError(f"the CAN traffic is already recorded to {self.can_recorder.path}")
        self.can_recorder = CanRecorder(path)
        for bus in self.group.buses:
            bus.record_to(self.can_recorder)
        return self.can_recorder.path

    @property
    def can_timeout(self) -> float:
        """The CAN watchdog armed at ``start()``, s (0: the motors keep their own); for run metadata."""
        return min((m.can_timeout for bus in self.group.buses for m in bus.motors), default=0.0)

    def run_metadata(self) -> dict[str, object]:
        """For the run log: the armed CAN watchdog (``can_timeout``, s; 0 = left to the motors).

        Only when they happened: ``activation_retries`` (retries of a missing reply the start-up needed, and
        per step in ``activation_retries_by_step``), ``temperature_warnings`` (joint -> readings at or above
        its warning threshold) with ``max_temperature`` (joint -> highest reading, degC).
        """
        meta: dict[str, object] = {"can_timeout": self.can_timeout}
        if self.startup is not None and self.startup.retries_used:
            meta["activation_retries"] = self.startup.total_retries
            meta["activation_retries_by_step"] = dict(self.startup.retries_used)
        warned = self.group.temperature.counts()
        if warned:
            meta["temperature_warnings"] = warned
            top = dict(zip(self.joint_names, self.group.temperature.max_seen, strict=True))
            meta["max_temperature"] = {n: float(top[n]) for n in warned}
        return meta

    def temperatures(self) -> np.ndarray:
        """The latest feedback temperature per joint, canonical order, degC (NaN: no reply yet).

        For the run log: the state the target returns (``JointState``) has no temperature field.
        """
        r = self._reading
        return np.full(self.num_joints, np.nan) if r is None else r.temperature.copy()

    # ----------------------------------------------------------------------------------------------
    def start(self) -> None:
        """Scan, verify, write caps, enable and hold damping (or only check, in a dry run).

        On failure the buses (and companions) are closed and ``TargetError`` is raised from the driver's
        ``InitializationError`` (or other ``RobstrideError``); anything enabled was damped and stopped first.

        ``stop_requested`` is checked before every step (scan, model and watchdog reads, joint read, each
        motor's cap writes, arming, enable, damping hold): once it is true the start-up ends with
        ``TargetError`` ("start-up stopped: ...") and nothing more is written or enabled. A missing reply
        is retried ``activation_retries`` times (backoff ``retry_backoff`` s, doubling) before refusing;
        the retries needed are logged and kept in ``startup`` and ``run_metadata``.
        """
        self.startup = StartupControl(
            retries=self.activation_retries, backoff=self.retry_backoff, stop_requested=self.stop_requested
        )
        try:
            self.startup.check_stop("the start-up")
            reading = self.group.activate(
                lower=self.robot.lower,
                upper=self.robot.upper,
                scan_ids=self.scan_ids,
                limit_margin=self.limit_margin,
                dry_run=self.dry_run,
                damping_kd=self.damping_kd,
                control=self.startup,
            )
        except StopRequestedError as exc:
            log.warning("real target: start-up stopped: %s", exc)
            self.close()
            raise TargetError(f"start-up stopped: {exc}") from exc
        except RobstrideError as exc:
            log.error("real target: activation failed: %s", exc)
            self.close()
            raise TargetError(f"activation refused: {exc}") from exc
        except BaseException:
            self.close()
            raise
        self._reading = reading
        if not self.dry_run:
            self.enabled = True
            self._last_cmd = MitCommand.damping(reading.q, self.damping_kd)
        log.info(
            "real target started (%s): q = %s",
            "dry run" if self.dry_run else "enabled",
            np.round(reading.q, 3),
        )

    def _fail(self, exc: RobstrideError) -> NoReturn:
        log.error("real target: %s -> damping, then stop", exc)
        self.safe_stop()
        raise TargetError(str(exc)) from exc

    def _guarded(self, fn: Callable[..., _T], *args: object) -> _T:
        """Run a bus operation; on any failure: damping, stop, raise."""
        try:
            return fn(*args)
        except RobstrideError as exc:
            self._fail(exc)
        except BaseException:
            log.error("real target: interrupted -> damping, then stop")
            self.safe_stop()
            raise

    def _check_running(self) -> None:
        if self.stopped:
            raise TargetError("the real target was stopped (damping then stop); restart it to continue")
        if not self.enabled and not self.dry_run:
            raise TargetError("the real target is not started; call start() first")

    def read_state(self) -> JointState:
        """Fresh joint state (see the module docstring)."""
        self._check_running()
        if self.dry_run:
            reading = self._guarded(lambda: self.group.poll_disabled(strict=False))
            log.debug("dry run: q=%s faults=%s", np.round(reading.q, 4), reading.faults)
        elif self.refresh_on_read and self._last_cmd is not None:
            reading = self._guarded(self.group.exchange_mit, self._last_cmd)
        else:
            reading = self._reading
        self._reading = reading
        return self._state(reading)

    def _state(self, r: BusReading) -> JointState:
        """The joint state of a reading; its faults: fault bits, and joints at their over-temperature limit.

        A temperature at or above the model's fault threshold (``robstride.temperature``) is reported in
        ``faults`` like the firmware's fault bits, so the runtime damps and stops; the first reading of a
        joint at or above its warning threshold is logged once (and counted, ``run_metadata``).
        """
        faults = tuple(
            f"{name}: {', '.join(fault_names(int(bits)))}"
            for name, bits in zip(self.joint_names, r.faults, strict=True)
            if bits
        ) + self.group.temperature.check(r.temperature)
        return JointState(q=r.q.copy(), dq=r.dq.copy(), tau=r.tau.copy(), stamp=r.stamp, faults=faults)

    def write_command(self, cmd: MitCommand) -> None:
        """One MIT round on every bus (canonical order, joint frame, fields shape (num_joints,))."""
        self._check_running()
        fields = [np.asarray(f, dtype=np.float64) for f in cmd]
        bad = [
            name
            for name, f in zip(MitCommand._fields, fields, strict=True)
            if f.shape not in ((), (self.num_joints,))
        ]
        if bad:
            self._fail(CommandError(f"command fields {bad} must have shape ({self.num_joints},)"))
        cmd = MitCommand(*fields)
        if self.dry_run:
            frames = self._guarded(self.group.mit_frames, cmd)
            for bus, bus_frames in zip(self.group.buses, frames, strict=True):
                for f in bus_frames:
                    req = decode_request(*f)
                    log.debug(
                        "dry run %s: %s -> %s", bus.interface, f, req.setpoint(bus.models[req.motor_id])
                    )
            return
        self._reading = self._guarded(self.group.exchange_mit, cmd)
        self._last_cmd = cmd

    def use_stop_torque(self, tau_ff: Callable[[np.ndarray], np.ndarray] | None) -> None:
        """The safe stop's damping frames carry ``tau_ff(q)`` at the measured q, N*m (n,); None: 0."""
        self._stop_torque = tau_ff

    def safe_stop(
        self, q: np.ndarray | None = None, kd: float | None = None, *, hold_s: float | None = None
    ) -> StopReport:
        """Damping (Kp = 0) at ``q`` (default: the last reading), then stop frames on every bus; who replied.

        Damping frames are repeated for ``hold_s`` s (default ``damping_hold_s``) at most every 10 ms, with
        ``tau_ff`` from ``use_stop_torque`` at each round's measured q; then one stop frame per motor, one
        motor at a time per bus (``RobstrideGroup.stop_each``). Best effort: errors are logged, the stop
        frames always go out. ``damping_answered`` is the last damping round's replies, ``stop_answered``
        only replies carrying the joint's own id after its own stop frame. Runs once: when the target was
        already stopped, nothing is sent and the first report is returned. A dry run sent nothing and
        enabled nothing: every joint counts as answered.
        """
        if self.stop_report is not None:
            return self.stop_report
        if self.dry_run:
            self.stopped = True
            self.stop_report = StopReport.all_answered(
                self.joint_names, "dry run: nothing was enabled, no frames sent"
            )
            return self.stop_report
        if q is None and self._reading is not None:
            q = self._reading.q
        damped = np.zeros(self.num_joints, dtype=bool)
        stopped = np.zeros(self.num_joints, dtype=bool)
        hold = self.damping_hold_s if hold_s is None else max(0.0, float(hold_s))
        try:
            damped = self._damping_rounds(q, self.damping_kd if kd is None else kd, hold)
        finally:
            try:
                stopped = self.group.stop_each()
            finally:
                self.enabled = False
                self.stopped = True
                self.stop_report = StopReport(
                    self.joint_names, tuple(map(bool, damped)), tuple(map(bool, stopped))
                )
        if not self.stop_report.confirmed:
            log.warning("real target: %s", self.stop_report.summary())
        return self.stop_report

    def _damping_rounds(self, q: np.ndarray | None, kd: float, hold_s: float) -> np.ndarray:
        """Damping frames at ``q`` (rad; None: the last reading) for ``hold_s`` s; who replied last."""
        if q is None:
            last = self.group.last_reading
            q = last.q if last is not None else np.zeros(self.num_joints)
        q = np.where(np.isfinite(q), q, 0.0)
        measured = q
        answered = np.zeros(self.num_joints, dtype=bool)
        end = time.monotonic() + hold_s
        while True:
            cmd = MitCommand.damping(q, kd)
            if self._stop_torque is not None:
                try:
                    cmd = cmd._replace(tau_ff=np.asarray(self._stop_torque(measured), dtype=np.float64))
                except Exception:
                    log.exception("stop torque failed: damping without it")
                    self._stop_torque = None
            try:
                frames = self.group.mit_frames(cmd)
            except RobstrideError as exc:
                log.error("damping frames: %s", exc)
                break
            answered, reading = self._best_effort_answers(frames)
            measured = np.where(np.isfinite(reading), reading, measured)
            if time.monotonic() >= end:
                break
            time.sleep(min(0.01, max(0.0, end - time.monotonic())))
        return answered

    def _best_effort_answers(self, frames: Sequence[Sequence[object]]) -> tuple[np.ndarray, np.ndarray]:
        """Send ``frames[b]`` on every bus independently, collect non-strictly.

        Returns which joints replied, bool (n,), and the replies' q, rad (n,; NaN where none came).
        """
        index = {name: i for i, name in enumerate(self.joint_names)}
        answered = np.zeros(self.num_joints, dtype=bool)
        q = np.full(self.num_joints, np.nan)
        sent = []
        for bus, bus_frames in zip(self.group.buses, frames, strict=True):
            try:
                sent.append((bus, bus.send_round(bus_frames)))
            except RobstrideError as exc:
                log.error("%s: cannot send the damping frames: %s", bus.interface, exc)
        for bus, deadline in sent:
            try:
                reading = bus.collect_round(deadline, strict=False)
            except RobstrideError as exc:
                log.error("%s: damping replies: %s", bus.interface, exc)
                continue
            for motor, mode, qi in zip(bus.motors, reading.mode, reading.q, strict=True):
                answered[index[motor.name]] = bool(mode >= 0)
                q[index[motor.name]] = qi
        return answered, q

    def close(self) -> None:
        """Damping then stop if still enabled, then close the buses and companions. Safe to call twice."""
        if self._closed:
            return
        try:
            if self.enabled and not self.stopped:
                self.safe_stop()
        finally:
            self._closed = True
            if self.group.temperature.counts():
                log.warning("real target: temperature warnings: %s", self.group.temperature.summary())
            self.group.shutdown()
            if self.can_recorder is not None:
                self.can_recorder.stop()
            for c in self.companions:
                c.close()  # type: ignore[attr-defined]
