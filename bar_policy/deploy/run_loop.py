"""The run of a ``Runtime`` around its ticks: the loop, the log, the end reason and the safe ending.

``RunLoop`` is the base of ``deploy.runtime.Runtime``: it holds ``run`` (the paced loop over
``Runtime._tick``), the run log's opening and closing, ``quality_record``, the final end reason and the
safe ending (DAMPING, ``target.safe_stop()``, the ``StopReport``). The state it reads (``policy``,
``target``, ``commands``, ``config``, ``safety``, ...) is set by ``Runtime.__init__``; see
``deploy.runtime`` for the start-up, fault and stop rules.
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bar_policy.deploy.log.files import CAN_LOG_FILE, LogDirError, log_fields
from bar_policy.deploy.log.foxglove_scene import RobotScene
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.run_config import RunResult
from bar_policy.deploy.safety import Mode
from bar_policy.deploy.targets.base import StopReport, TargetError, run_metadata_of
from bar_policy.deploy.timing import FrozenHeap, Pacer, RealtimePriority
from bar_policy.quality import summarise
from bar_policy.robot.mjcf import lite_xml
from bar_policy.signals import StopSignals

__all__ = ["RunLoop"]

log = logging.getLogger("bar_policy.deploy.runtime")  # the runtime's logger, as before the split

_MAX_FAULTS_KEPT = 32
"""Distinct faults kept for the run record (``faults``); a run that faults every tick repeats itself."""
_NUMBER = re.compile(r"[-+]?\d[\d.]*(?:e[-+]?\d+)?")
"""A number in a fault's text (two faults that differ only in numbers are the same fault, counted)."""


def _one_line(e: BaseException) -> str:
    """The exception's message on one line."""
    return " ".join(str(e).split())


class RunLoop:
    """The loop and the safe ending of a ``Runtime`` (its base class; the state comes from ``Runtime``)."""

    def _log_transitions(self) -> None:
        trs = self.safety.transitions
        if self._runlog is not None:
            for tr in trs[self._transitions_logged :]:
                self._runlog.transition(tr.to_dict())
        self._transitions_logged = len(trs)

    def _meta(self) -> dict[str, Any]:
        p = self.policy
        return {
            "policy": str(p.path),
            "task": p.metadata.task,
            "mode": p.robot.mode,
            "obs_fingerprint": p.obs_manager.fingerprint,
            "policy_code_version": p.metadata.code_version,
            "action_clip": p.action_clip,
            "target": type(self.target).__name__,
            "synchronous": self.target.synchronous,
            "commands": self.commands.describe(),
            "deploy_task": p.task,
            "command_source": self.commands.metadata(),
            "joint_names": list(p.robot.joint_names),
            "action_joint_names": list(p.metadata.action_joint_names),
            "mode_names": {m.name: int(m) for m in Mode},
            "policy_dialect": p.metadata.dialect,
            "hold_pose": self.hold_pose.tolist(),
            "runtime_config": asdict(self.config),
        } | self.log_meta

    def quality_record(self) -> dict[str, Any]:
        """The run's POLICY ticks as one episode (``EpisodeQuality``) with its summary figures."""
        fault = self._end_reason if self.safety.fault_count and not self._stop_reason else ""
        rec = self.quality.finish(self.log_name, fault)
        return {"episode": rec.to_dict(), "summary": summarise([rec]) if rec.ticks else {}}

    # -- the loop ------------------------------------------------------------------------------------
    def run(self, stop: StopSignals | None = None) -> RunResult:
        """Run until the duration, a fault, a stop request or the end of the commands, or an exception.

        A fault or a stop is followed by ``damping_after_fault`` s of damping, the end of the commands by
        ``end_hold`` s of HOLD, before the safe ending.

        Args:
            stop: the caller's installed ``StopSignals`` (``bar-deploy`` installs them before the target
                starts); None installs its own for the run when ``config.handle_signals``.

        Returns:
            The result with timing statistics. Exceptions propagate after the safe ending and the log.
        """
        if stop is None:
            stop = StopSignals()
            installed = stop if self.config.handle_signals else contextlib.nullcontext()
        else:
            installed = contextlib.nullcontext()
        with installed:
            return self._run(stop)

    def open_log(self) -> Path | None:
        """Create the run directory and start the log now (``run`` does it otherwise); idempotent.

        ``bar-deploy`` calls it before the target starts: a log directory that cannot be written is then
        refused before anything moves, and no file-system work (``fsync``) falls between the real target's
        activation and the first tick, which must come within the motors' CAN watchdog.

        A target with ``record_can`` (the real one) records its raw CAN traffic to ``run.blf`` in it from
        here on (``robstride.can_record``).

        Returns:
            The run directory, or None without ``log_dir``.

        Raises:
            LogDirError: the run directory, or the CAN log in it, cannot be created or written.
        """
        if self._runlog is None and self.log_dir is not None:
            self._runlog = self._make_log()
            self._record_can(self._runlog)
        return None if self._runlog is None else self._runlog.path

    def _record_can(self, runlog: RunLog) -> None:
        """A target with ``record_can`` (the real one) records its raw CAN traffic to ``run.blf``.

        Raises:
            LogDirError: the file cannot be created (the log is closed as not started).
        """
        record = getattr(self.target, "record_can", None)
        if record is None:
            return
        try:
            record(runlog.path / CAN_LOG_FILE)
        except (OSError, ValueError) as e:
            reason = f"cannot record the CAN traffic in {runlog.path}: {e}"
            runlog.close(end_reason=f"not started: {reason}", transitions=[], fault_count=0)
            self.log_path = runlog.path / "log.npz"
            raise LogDirError(reason) from None

    def close_unstarted(self, reason: str) -> None:
        """Close a log opened by ``open_log`` for a run that never started (``end_reason`` = ``reason``)."""
        if self._runlog is not None and not self._runlog.closed:
            self._runlog.close(end_reason=reason, transitions=[], fault_count=0)
            self.log_path = self._runlog.path / "log.npz"

    def _make_log(self) -> RunLog:
        om = self.policy.obs_manager
        robot = self.policy.robot
        fields = log_fields(robot.num_joints, self.policy.n_actions, om.size, self.commands.log_fields)
        return RunLog(
            self.log_dir,
            fields,
            self._meta(),
            name=self.log_name,
            labels={"mode": {int(m): m.name for m in Mode}},
            scene=RobotScene.for_mode(robot.mode, robot.joint_names),
            model_xml=lite_xml(robot.mode),
            live=self.live,
        )

    def _run(self, stop: StopSignals) -> RunResult:
        cfg = self.config
        dt = cfg.control_dt
        sync = self.target.synchronous
        paced = not sync or cfg.realtime
        # The duration in deadlines: wall-clock time when paced (a late tick skips deadlines, so fewer ticks
        # run), ticks of target time when not.
        n_deadlines = None if cfg.duration is None else max(round(cfg.duration / dt), 1)
        self.open_log()
        runlog = self._runlog
        k = 0
        t = 0.0
        end_reason = "duration reached"
        t0_target = self.target.now()
        pacer = Pacer(dt, paced=paced, spin_s=cfg.spin_s, n_deadlines=n_deadlines)
        error: BaseException | None = None
        try:
            with FrozenHeap(), RealtimePriority(cfg.rt_priority):
                while n_deadlines is None or pacer.index < n_deadlines:
                    start, lateness = pacer.wait()
                    t = k * dt if sync else self.target.now() - t0_target
                    if stop.requested:
                        self.request_stop(stop.reason)
                    try:
                        rec = self._tick(k, t, self._pending_stop)
                    except TargetError as e:  # the target stopped itself (the real one): the run ends here
                        self._fault("target", _one_line(e), t)
                        break
                    overran = pacer.tick_done(lateness, rec["compute"], rec["infer"])
                    rec.update(jitter=lateness, overrun=overran, wall=start - pacer.wall0)
                    if runlog is not None:
                        runlog.append(rec)
                    if sync:
                        try:
                            self.target.advance(dt)
                        except TargetError as e:  # the simulator cannot go on (its viewer was closed)
                            self._fault("target", _one_line(e), t)
                            self._log_transitions()
                            k += 1  # the tick ran and is in the log
                            break
                    else:
                        ov = self.safety.note_overrun(overran)
                        if ov is not None:
                            self._fault(*ov, t)
                    self._log_transitions()
                    if self.safety.mode == Mode.POLICY:  # the ticks a task scores (the piano's F1)
                        self.commands.after_policy_tick()
                    if self.on_tick is not None:
                        self.on_tick(k, t, self)
                    k += 1
                    if self._end_t is not None and t - self._end_t >= self._end_after - 1e-9:
                        break
            end_reason = self._final_reason(end_reason)
        except BaseException as e:
            error = e
            self._note_fault(f"exception {type(e).__name__}: {_one_line(e)}")
            end_reason = self._first_fault or f"exception {type(e).__name__}: {e}"
            raise
        finally:
            t_end = self.target.now() - t0_target
            timing = pacer.stats(k * dt if sync else t_end)  # the loop alone, without the safe ending
            safe_stop, report = self._safe_end(end_reason, t_end)
            self._log_transitions()
            log_path = None
            later = self.later_faults(end_reason)
            if runlog is not None:
                try:
                    log_path = runlog.close(
                        end_reason=end_reason,
                        later_faults=list(later),
                        faults=list(self.faults),
                        fault_repeats=list(self.fault_repeats),
                        target_metadata=run_metadata_of(self.target),
                        stop_reason=self._stop_reason,
                        stop_signal=stop.signal_name,
                        stop_signals_received=stop.count,
                        safe_stop=safe_stop,
                        stop_report=None if report is None else report.to_dict(),
                        stop_damping=self.stop_damping_record(),
                        hand_load=self.hand_load_record(),
                        exception=None if error is None else f"{type(error).__name__}: {error}",
                        transitions=[tr.to_dict() for tr in self.safety.transitions],
                        timing=timing.summary(),
                        clip_count=self.safety.clip_count,
                        action_clip_count=self.action_clip_count,
                        action_count=self.actions.count,
                        fault_count=self.safety.fault_count,
                        command_outside_workspace=self.commands.outside_count,
                        completed=self.completed,
                        quality=self.quality_record(),
                    )
                except Exception:
                    log.exception("could not write the run log in %s", runlog.path)
                    if error is None:
                        raise
            self.log_path = log_path
            self.result = RunResult(
                ticks=k,
                final_mode=self.safety.mode,
                transitions=[tr.to_dict() for tr in self.safety.transitions],
                timing=timing,
                end_reason=end_reason,
                clip_count=self.safety.clip_count,
                fault_count=self.safety.fault_count,
                log_path=log_path,
                last_state=self.last_state,
                action_clip_count=self.action_clip_count,
                stop_reason=self._stop_reason,
                safe_stop=safe_stop,
                stop_confirmed=report is not None and report.confirmed,
                stop_unconfirmed=() if report is None else report.unconfirmed,
                completed=self.completed,
                quality=self.quality_record(),
                action_count=self.actions.count,
                later_faults=later,
                hand_load=self.hand_load_record(),
            )
        return self.result

    def _note_fault(self, text: str) -> None:
        """Keep ``text`` in ``faults``: each distinct fault once, in the order they first came.

        Faults that differ only in their numbers (a stale state 120 ms old, then 140 ms) are one fault,
        counted in ``fault_repeats``.
        """
        key = _NUMBER.sub("#", text)
        if key in self._fault_keys:
            self.fault_repeats[self._fault_keys[key]] += 1
        elif len(self.faults) < _MAX_FAULTS_KEPT:
            self._fault_keys[key] = len(self.faults)
            self.faults.append(text)
            self.fault_repeats.append(1)

    def later_faults(self, end_reason: str) -> tuple[str, ...]:
        """The distinct faults after the one the end reason names (the end reason's own excluded)."""
        return tuple(f for f in self.faults if f not in end_reason)

    def _final_reason(self, loop_reason: str) -> str:
        """The end reason: the run's first fault whenever one occurred, else why the loop ended."""
        reason = self._end_reason if self._end_t is not None else loop_reason
        first = self._first_fault
        if first is None or first in reason:
            return reason
        if self._stop_reason is not None and reason == self._end_reason:
            return f"{first} (during the stop: {reason})"
        return first

    def _safe_end(self, reason: str, t: float) -> tuple[str, StopReport | None]:
        """DAMPING (logged with the reason), then the target's safe stop; errors here are logged only.

        The run holds damping for ``damping_after_fault`` s once, whatever ended it: the loop's DAMPING ticks
        after a fault or a stop count towards it, the target's safe stop holds the rest (``hold_s``; the
        whole of it after the duration, a finished clip or an exception). A target that already stopped
        itself (the real one after a driver error) sends nothing more and returns its report.

        Returns:
            The outcome (``StopReport.summary()``, or ``"failed: ..."`` with the error ``target.safe_stop``
            raised) and the report (None when it raised); both are also kept in ``safe_stop_summary`` and
            ``stop_report``.
        """
        sf = self.safety
        damped = 0.0
        if sf.mode == Mode.DAMPING and self._end_t is not None and not self.completed:
            damped = max(0.0, t - self._end_t)
        hold = max(0.0, self.config.damping_after_fault - damped)
        if sf.mode in (Mode.HOLD, Mode.POLICY, Mode.ZERO_TORQUE):
            level = logging.INFO if reason == "duration reached" or self.completed else logging.WARNING
            sf.transition(Mode.DAMPING, f"run ended: {reason}", t, level=level)
        self.stop_hold_s = hold
        try:
            report = self.target.safe_stop(sf.captured_q, sf.config.damping_kd, hold_s=hold)
        except Exception as e:
            log.exception("safe_stop of %s failed", type(self.target).__name__)
            self.safe_stop_summary = f"failed: {type(e).__name__}: {e}"
            return self.safe_stop_summary, None
        if not isinstance(report, StopReport):  # a target from before the report: it did not say
            report = StopReport(
                self.target.joint_names,
                (False,) * self.target.num_joints,
                (False,) * self.target.num_joints,
                f"{type(self.target).__name__}.safe_stop reports no replies",
            )
        self.stop_report = report
        self.safe_stop_summary = report.summary()
        if not report.confirmed:
            log.warning("safe stop: %s", self.safe_stop_summary)
        return self.safe_stop_summary, report
