"""The fixed-rate control loop: state -> observation -> ONNX -> MIT command, under the safety supervisor.

Each tick: read the target's state, check it (safety), fetch the task's command terms from the command
source (``deploy.tasks``: reach targets, a motion reference, ...), build the observation with the frozen
``ObservationManager`` (the state terms from ``deploy.inputs``: joint_pos / joint_vel from the measured
state, ``actions`` = the previous raw policy output, fingertips by forward kinematics of the measured q when
the layout has them), run the policy in POLICY mode, clip the raw action to ``+-policy.action_clip`` and
low-pass it when the file has an action filter (``deploy.action_path``: the env's code, counted), turn it
into ``q_cmd = default + action_scale * action`` (clipped to the joint limits and counted by the
supervisor), check the torque demand, write the command, record the tick. The ``actions`` observation term
is the previous applied action, as in the env. Every POLICY tick also feeds the run's safety and
smoothness record (``bar_policy.quality``: torque caps, joint limits, action rate, chatter of ``q_cmd``
minus the reference the source targets, or of ``q_cmd`` itself), in ``RunResult.quality`` and the log.

Scheduling (``timing.Pacer``) uses absolute deadlines ``t0 + k * dt`` (no drift): an asynchronous target
(mock, real bus) is paced against the wall clock, with overruns counted and missed deadlines skipped; a
synchronous target (sim) is not paced: the loop calls ``target.advance(dt)`` and runs as fast as it can
(``realtime=True`` paces it for the viewer).

A ``TargetError`` from the target mid-run is the fault ``target``: the loop ends at once (the real target
has already damped and stopped), and the run ends as any fault does, without an exception. The DAMPING
after a fault or a stop carries the gravity torque at the measured q as ``tau_ff`` (``deploy.gravity``;
``RuntimeConfig.stop_damping``), which the target's own safe stop uses too (``Target.use_stop_torque``).
POLICY and the end's HOLD carry the hand-load fit's feed-forward in ``tau_ff``, and POLICY the load's
inertia from a reference arm (``deploy.load_compensation``: ``RuntimeConfig.hand_load`` and
``load_inertia``, by default the command source's), checked by the saturation rule with the rest.

Start-up: ZERO_TORQUE until the first state; a valid first state gives DAMPING then HOLD (ramp to the
command source's ``hold_pose``, else the policy's rest pose ``policy.hold_pose``, over
``safety.ramp_time``; with the hand-load ``tare``, then held still ``start_tare_s`` while the fit tares)
then POLICY, where the source's phase 0 begins (``source.begin(t)``);
``start_mode="policy"`` skips the ramp (evaluation). A fault latches DAMPING; the run then continues in
DAMPING for ``damping_after_fault`` s and ends. The end reason (``RunResult.end_reason``, the log's
``end_reason``) names the FIRST fault whenever one occurred: also when the duration runs out during the
damping after it, or when it came during a requested stop's damping (``"fault K: ... (during the stop:
R)"``).

Actions: a non-finite action is a fault at once; a policy that keeps asking far beyond its action range
(``SafetyConfig.action_range_factor`` x the clip bound for longer than ``action_range_time``: 4x for 0.2 s
by default) faults with ``action_out_of_range``. The construction refuses (``PolicyLoadError``) a policy
whose ``action_scale`` reaches beyond the joint ranges by more than ``RuntimeConfig.action_reach_margin``
(``safety.check_action_scale``).

The end of the commands: once the source is ``finished`` (a motion clip at its last frame), POLICY gives
way to HOLD at the source's ``end_pose`` with the policy's gains (the pose ramps over half of
``end_hold``) for ``end_hold`` s, then the run ends as completed through the usual safe ending. The loop
never names a task: it only knows the ``CommandSource`` interface (``bar_policy.tasks.interfaces``).

Stopping: SIGINT, SIGTERM and SIGHUP (``StopSignals``; the caller's, or installed by ``run`` in
the main thread) and ``request_stop`` all take one path: the next tick enters DAMPING with the reason, the
loop keeps damping for ``damping_after_fault`` s, then ends. A requested stop is not a fault. The run
always ends through ``finally``: DAMPING, ``target.safe_stop(hold_s=...)`` (the rest of
``damping_after_fault`` not yet damped by the loop, then stop frames on every bus on the real target; it
runs once: a real target that already stopped itself after a driver error returns its report), then the
log is closed with the reason and the stop path's outcome: the target's ``StopReport``
(which joints answered the damping and the stop frames); ``RunResult.safe_stop`` says ``"stop confirmed
(...)"`` only when every joint answered, else it names the joints that did not, and
``RunResult.exit_status`` is ``EXIT_STOP_UNCONFIRMED`` (3; ``run_config``). The signal handlers stay
installed until the log is closed and never raise, so a second signal cannot cut the stop frames short.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.deploy.action_path import ActionPath
from bar_policy.deploy.contract import PolicyLoadError
from bar_policy.deploy.gravity import GravityTorque
from bar_policy.deploy.inputs import StateInputs
from bar_policy.deploy.load_compensation import LoadCompensation
from bar_policy.deploy.log.live import LiveServer
from bar_policy.deploy.log.run_log import RunLog
from bar_policy.deploy.policy import OnnxPolicy, action_reach_problems
from bar_policy.deploy.run_config import RunResult, RuntimeConfig
from bar_policy.deploy.run_loop import RunLoop
from bar_policy.deploy.safety import Mode, SafetySupervisor
from bar_policy.deploy.targets.base import JointState, StopReport, Target
from bar_policy.deploy.timing import TimingStats, sleep_until
from bar_policy.quality import QualityMeter
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mit import MitCommand, mit_torque
from bar_policy.tasks.interfaces import CommandSource

__all__ = ["RunResult", "Runtime", "RuntimeConfig", "TimingStats", "sleep_until"]

log = logging.getLogger(__name__)


class Runtime(RunLoop):
    """Runs a policy on a target at a fixed rate under the safety supervisor."""

    def __init__(
        self,
        policy: OnnxPolicy,
        target: Target,
        commands: CommandSource,
        config: RuntimeConfig | None = None,
        *,
        log_dir: str | Path | None = None,
        log_meta: Mapping[str, Any] | None = None,
        log_name: str = "run",
        kinematics: Kinematics | None = None,
        on_tick: Callable[[int, float, Runtime], None] | None = None,
        live: LiveServer | None = None,
    ) -> None:
        """Wire a policy, a target and a command source.

        Args:
            policy: a loaded, contract-checked policy.
            target: the joints (started by the caller; the runtime never starts or closes it).
            commands: the task's command source (``deploy.tasks``); it must feed every command term of the
                policy's layout.
            config: loop settings.
            log_dir: parent directory of the run log; None records nothing.
            log_meta: extra JSON metadata for the run log.
            log_name: suffix of the run directory.
            kinematics: fingertip FK (built for the policy's mode when the layout has fingertips and None).
            on_tick: called after every tick with (tick, run time, runtime) (tests, evaluation).
            live: a live server (``deploy.log.live``) that gets the run log's channels too (needs ``log_dir``;
                the caller starts and stops it).
        """
        self.policy = policy
        self.target = target
        # The target's per-joint temperature reader (the real target has one), looked up once, not per tick.
        self._read_temperatures = getattr(target, "temperatures", None)
        self.commands = commands
        commands.attach(target)
        self.config = config or RuntimeConfig()
        robot = policy.robot
        if tuple(target.joint_names) != robot.joint_names:
            raise ValueError(
                f"target joints {list(target.joint_names)} differ from the policy's {list(robot.joint_names)}"
            )
        if abs(policy.policy_dt - self.config.control_dt) > 1e-9:
            raise ValueError(
                f"policy dt {policy.policy_dt} s differs from control dt {self.config.control_dt} s"
            )
        missing = [n for n in policy.obs_manager.command_names if n not in commands.names]
        if missing:
            raise ValueError(
                f"command source {commands.describe()} (task {commands.task!r}) does not feed {missing}, "
                f"which the policy (task {policy.task!r}) reads; its commands: {list(commands.names)}"
            )
        self._check_action_scale(policy)
        hold = commands.hold_pose
        self.hold_pose = policy.hold_pose if hold is None else np.asarray(hold, dtype=np.float64)
        """Where the start-up HOLD ramp goes: the source's ``hold_pose``, else the policy's, rad."""
        self.safety = SafetySupervisor(
            joint_names=robot.joint_names,
            lower=robot.lower,
            upper=robot.upper,
            torque_cap=robot.torque_cap,
            kp=policy.kp,
            kd=policy.kd,
            default_q=self.hold_pose,
            config=self.config.safety,
        )
        self.gravity = GravityTorque(robot.mode) if self.config.stop_damping == "gravity" else None
        """``tau_ff`` of the DAMPING after a fault or a stop, and of the target's own safe stop (None:
        damping alone; ``deploy.gravity``)."""
        self.loads = LoadCompensation(self.config, commands, target, robot.mode)
        """The hand-load fit and the load-inertia feed-forward POLICY and the end's HOLD add to ``tau_ff``
        (``deploy.load_compensation``)."""
        use_stop_torque = getattr(target, "use_stop_torque", None)
        if use_stop_torque is not None:
            use_stop_torque(self.gravity)
        self.inputs = StateInputs(policy.obs_manager, robot.mode, kinematics, policy.policy_dt)
        self._policy_q_cmd: np.ndarray | None = None
        """The joint command the last tick wrote when it ran the policy, else None (``joint_error_ema``)."""
        """The observation's state terms (``deploy.inputs``)."""
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.log_meta = dict(log_meta or {})
        self.log_name = log_name
        if live is not None and log_dir is None:
            raise ValueError("a live view serves the run log's channels: it needs a log directory")
        self.live = live
        self.on_tick = on_tick
        self.actions = ActionPath(policy)
        """The clip and the action filter; ``actions.last`` is the observation's ``actions`` term."""
        self.quality = QualityMeter(
            robot.torque_cap, robot.lower, robot.upper, self.config.control_dt, robot.joint_names
        )
        """Safety and smoothness of the POLICY ticks (``bar_policy.quality``)."""
        self.last_state: JointState | None = None
        self.last_commands: dict[str, np.ndarray] = {}
        self.last_command: MitCommand | None = None
        """The MIT command the last tick wrote (after the supervisor's clip and any fault's damping)."""
        self.dry_saturations = 0
        """Ticks whose demand was at the cap too long on a target that applies no command (a dry run)."""
        self._end_t: float | None = None
        """Target time the run started to end (first fault or stop request), s."""
        self._still_until: float | None = None
        """Target time the start's still dwell after the HOLD ramp ends (``start_tare_s``), s; None before
        the ramp completes."""
        self._end_reason = ""
        self._first_fault: str | None = None
        """``"fault KIND: detail"`` of the run's first fault (None: no fault)."""
        self.faults: list[str] = []
        """Every distinct ``"fault KIND: detail"`` (and an exception that ended the run), first first."""
        self.fault_repeats: list[int] = []
        """How often each of ``faults`` came (faults that differ only in their numbers count as one)."""
        self._fault_keys: dict[str, int] = {}
        self.result: RunResult | None = None
        """What the run did, set when it ended, also when it ended on an exception (which then propagates)."""
        self.stop_hold_s = 0.0
        """Damping the target's safe stop held before its stop frames, s (the rest of ``damping_after_fault``
        after the loop's DAMPING ticks)."""
        self.stop_report: StopReport | None = None
        """What the safe stop's frames got back (None until the run ended, or when ``safe_stop`` raised)."""
        self.safe_stop_summary = ""
        """The safe stop's outcome (``RunResult.safe_stop``), set also when the run ends on an exception."""
        self._action_names = tuple(policy.metadata.action_joint_names)
        self._end_after = self.config.damping_after_fault
        """How long the run goes on after ``_end_t``: damping after a fault or stop, HOLD after the end."""
        self.completed = False
        """True when the run ends because the command source finished (a motion clip played to its end)."""
        self._stop_reason: str | None = None
        self._pending_stop: str | None = None
        self._cap = robot.torque_cap
        self._runlog: RunLog | None = None
        self._transitions_logged = 0
        self.log_path: Path | None = None

    @property
    def last_action(self) -> np.ndarray:
        """The last applied action (the observation's ``actions`` term), float32 (n_actions,)."""
        return self.actions.last

    @property
    def action_clip_count(self) -> int:
        """Action entries clipped to ``+-policy.action_clip`` over the run."""
        return self.actions.clip_count

    # -- helpers -------------------------------------------------------------------------------------
    def _temperatures(self, n: int) -> np.ndarray:
        """Per-joint motor temperature, degC, from a target that reports one (the real target); else NaN."""
        read = self._read_temperatures
        return np.full(n, np.nan) if read is None else np.asarray(read(), dtype=np.float64)

    def _check_action_scale(self, policy: OnnxPolicy) -> None:
        """Refuse (``PolicyLoadError``) an ``action_scale`` that reaches beyond the joint ranges."""
        problems = action_reach_problems(policy, self.config.action_reach_margin)
        if problems:
            raise PolicyLoadError(
                f"{policy.path}: action_scale beyond the joint ranges: {'; '.join(problems)}"
            )

    def _unapplied_saturation(self, detail: str) -> None:
        """A torque saturation on a target whose commands never reach the joints (a dry run): no fault.

        The joints cannot follow a command that is not sent, so the demand ``Kp * (q_cmd - q)`` at the
        measured state grows with the ramp; it says nothing about the run. Counted (``dry_saturations``,
        ticks) and logged once; the demand stays in the log each tick.
        """
        if not self.dry_saturations:
            log.warning(
                "commands are not applied (dry run): %s - not a fault, the joints cannot follow", detail
            )
        self.dry_saturations += 1

    def _fault(self, kind: str, detail: str, t: float) -> None:
        if self._first_fault is None:
            self._first_fault = f"fault {kind}: {detail}"
        self._note_fault(f"fault {kind}: {detail}")
        changed = self.safety.fault(kind, detail, t)
        if changed and (self._end_t is None or self.completed):  # a fault in the final HOLD is a fault
            self._end_t, self._end_after = t, self.config.damping_after_fault
            self._end_reason = f"fault {kind}: {detail}"
            self.completed = False

    def hand_load_record(self) -> dict[str, Any]:
        """For the run log: the load compensation's record (``LoadCompensation.record``)."""
        return self.loads.record()

    def _with_stop_torque(self, cmd: MitCommand, q: np.ndarray) -> MitCommand:
        """In DAMPING with gravity compensation: ``tau_ff`` = the gravity torque at the measured ``q``."""
        if self.gravity is None or self.safety.mode != Mode.DAMPING:
            return cmd
        return cmd._replace(tau_ff=self.gravity(q))

    def stop_damping_record(self) -> dict[str, Any]:
        """For the run log: which damping the stops used and how it was held.

        ``kind`` (``gravity`` or ``plain``), ``damping_time_s`` (the configured damping), ``target_hold_s``
        (the part the target's safe stop held after the loop's DAMPING ticks), and with gravity the
        evaluations, the clipped joint-evaluations and the largest torque asked per joint.
        """
        rec: dict[str, Any] = {
            "kind": self.config.stop_damping,
            "damping_time_s": self.config.damping_after_fault,
            "target_hold_s": self.stop_hold_s,
        }
        if self.gravity is not None:
            rec["gravity"] = self.gravity.record()
        return rec

    def request_stop(self, reason: str) -> None:
        """Ask the loop to stop (DAMPING at the next tick, then the safe ending); the first reason is kept."""
        if self._pending_stop is None:
            self._pending_stop = reason

    def _stop(self, reason: str, t: float) -> None:
        """A stop request at target time ``t``: DAMPING now (not a fault); the run ends after the damping."""
        if self._stop_reason is None:
            self._stop_reason = reason
        sf = self.safety
        if sf.mode in (Mode.HOLD, Mode.POLICY):
            sf.transition(Mode.DAMPING, f"stop requested: {reason}", t, level=logging.WARNING)
        if self._end_t is None:
            self._end_t, self._end_after = t, self.config.damping_after_fault
            self._end_reason = reason

    def _finish(self, reason: str, t: float) -> None:
        """The command source finished: POLICY -> HOLD at its end pose (gains kept); the run completes."""
        end = self.commands.end_pose
        target = self.last_state.q if end is None else end
        self.safety.transition(
            Mode.HOLD,
            f"commands finished: {reason}",
            t,
            hold_target=target,
            hold_ramp=0.5 * self.config.end_hold,
        )
        self._end_t, self._end_after, self._end_reason = t, self.config.end_hold, reason
        self.completed = True

    # -- one tick ------------------------------------------------------------------------------------
    def _tick(self, k: int, t: float, stop: str | None = None) -> dict[str, Any]:
        """One control tick at target time ``t``; ``stop``: a stop request's reason (None: keep running)."""
        t_start = time.perf_counter()
        stop = stop or None  # False / "" (older callers) mean no stop
        sf = self.safety
        sf.tick = k
        state = self.target.read_state()
        self.last_state = state
        fault = sf.check_state(state, self.target.now())
        if fault is not None:
            self._fault(*fault, t)
        if sf.mode == Mode.ZERO_TORQUE:
            if fault is not None or stop is not None:
                reason = f"start refused: fault {fault[0]}: {fault[1]}" if fault else f"start refused: {stop}"
                sf.transition(Mode.DAMPING, reason, t, level=logging.WARNING)
                if stop is not None and fault is None:
                    self._stop(stop, t)
                else:
                    self._end_t, self._end_reason = t, reason
            else:
                sf.transition(Mode.DAMPING, "first valid state received", t)
                if self.config.start_mode == "hold":
                    where = (
                        "the default pose" if self.commands.hold_pose is None else "the commands' start pose"
                    )
                    sf.transition(Mode.HOLD, f"ramp to {where} over {sf.config.ramp_time:g} s", t)
                else:
                    self._start_policy("start_mode=policy (no ramp)", t)
        if stop is not None:
            self._stop(stop, t)
        still = False
        if sf.mode == Mode.HOLD and self._end_t is None and sf.ramp_complete(t):
            dwell = self.config.start_tare_s if self.loads.start_tare else 0.0
            if self._still_until is None:
                self._still_until = t + dwell
            if t >= self._still_until - 1e-9:
                held = f"; held still {dwell:g} s for the hand-load tare" if dwell > 0 else ""
                self._start_policy(f"ramp complete{held}", t)
            else:
                still = True
        if sf.mode == Mode.POLICY:
            done = self.commands.finished(t)
            if done is not None:
                self._finish(done, t)

        self.commands.observe(state.q, state.dq)
        cmds = self.commands(t)
        self.last_commands = cmds
        inputs = self.inputs(state.q, state.dq, self.last_action, self._policy_q_cmd)
        inputs.update(cmds)
        obs = self.policy.obs_manager.compute(inputs)
        action = None
        q_policy = None
        infer = math.nan
        n_action_clipped = 0
        if sf.mode == Mode.POLICY:
            t_inf = time.perf_counter()
            action = self.policy(obs)
            infer = time.perf_counter() - t_inf
            bad = sf.check_action(action) or sf.check_action_range(
                action, self.actions.bound, self._action_names, self.config.control_dt
            )
            if bad is not None:
                self._fault(*bad, t)
            else:
                used, n_action_clipped = self.actions(action, t)
                q_policy = self.policy.q_command(used)
        cmd = self._with_stop_torque(sf.command(t, q_policy), state.q)
        cmd = self.loads(cmd, state, sf.mode, commanded=self.last_command is not None, still=still)
        applied = self.target.applies_commands
        sat = sf.check_torque(cmd, state, self.config.control_dt, use_reported=applied)
        demand = sf.last_demand
        if sat is not None and not applied:
            self._unapplied_saturation(sat[1])
            sat = None
        if q_policy is not None:
            ref = self.commands.target_q()
            self.quality.update(
                demand,
                state.q,
                self.actions.last,
                cmd.q if ref is None else cmd.q - ref,
                state.tau if applied else None,
            )
        if sat is not None:
            self._fault(*sat, t)
            cmd = self._with_stop_torque(sf.command(t, q_policy), state.q)  # DAMPING: no hand-load term
            demand = mit_torque(cmd, state.q, state.dq)
        self.target.write_command(cmd)
        self.last_command = cmd
        self._policy_q_cmd = cmd.q.copy() if q_policy is not None and sf.mode == Mode.POLICY else None
        compute = time.perf_counter() - t_start
        return {
            "t": t,
            "mode": int(sf.mode),
            "q": state.q,
            "dq": state.dq,
            "tau": state.tau,
            "temperature": self._temperatures(len(state.q)),
            "obs": obs,
            "action": np.nan if action is None else action,
            "q_cmd": cmd.q,
            "dq_cmd": cmd.dq,
            "kp": cmd.kp,
            "kd": cmd.kd,
            "tau_ff": cmd.tau_ff,
            "tau_cmd": np.minimum(np.maximum(demand, -self._cap), self._cap),
            "n_clipped": sf.last_clipped,
            "n_action_clipped": n_action_clipped,
            "compute": compute,
            "infer": infer,
            **self.commands.record(),
        }

    def _start_policy(self, reason: str, t: float) -> None:
        """Enter POLICY at ``t``: the filter starts at the HOLD target's action; the phase 0 begins."""
        self.safety.transition(Mode.POLICY, reason, t)
        self.actions.start(self.hold_pose)
        self.commands.begin(t)
