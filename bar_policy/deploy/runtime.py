"""The fixed-rate control loop: state -> observation -> ONNX -> MIT command, under the safety supervisor.

Each tick: read the target's state, check it (safety), fetch the commands (reach targets), build the
observation with the frozen ``ObservationManager`` (joint_pos / joint_vel from the measured state,
``actions`` = the previous raw policy output, fingertips by forward kinematics of the measured q), run the
policy in POLICY mode, clip the raw action to ``+-policy.action_clip`` (as the env does; counted), turn it
into ``q_cmd = default + action_scale * action`` (clipped to the joint limits and counted by the
supervisor), check the torque demand, write the command, record the tick. The ``actions`` observation term
is the previous clipped action, as in the env.

Scheduling uses absolute deadlines ``t0 + k * dt``, so errors never accumulate (no drift). An asynchronous
target (mock, real bus) is paced against ``time.perf_counter`` (sleep, then spin for the last
``spin_s``); a tick that ends after the next deadline is an overrun, and missed deadlines are skipped (the
grid keeps its phase). A synchronous target (sim) is not paced: the loop calls ``target.advance(dt)`` and
runs as fast as it can (``realtime=True`` paces it for the viewer).

Start-up: ZERO_TORQUE until the first state; a valid first state gives DAMPING then HOLD (ramp to the
policy's rest pose ``policy.hold_pose`` over ``safety.ramp_time``) then POLICY; ``start_mode="policy"``
skips the ramp (evaluation). A fault latches DAMPING; the run then continues in DAMPING for
``damping_after_fault`` s and ends.

Stopping: SIGINT, SIGTERM and SIGHUP (``signals.StopSignals``; the caller's, or installed by ``run`` in
the main thread) and ``request_stop`` all take one path: the next tick enters DAMPING with the reason, the
loop keeps damping for ``damping_after_fault`` s, then ends. A requested stop is not a fault. The run
always ends through ``finally``: DAMPING, ``target.safe_stop()`` (stop frames on every bus on the real
target), then the log is closed with the reason and the stop path's outcome. The signal handlers stay
installed until the log is closed and never raise, so a second signal cannot cut the stop frames short.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bar_policy.deploy.commands import CommandSource
from bar_policy.deploy.log import RunLog, log_fields
from bar_policy.deploy.policy import DEFAULT_CONTROL_DT, OnnxPolicy
from bar_policy.deploy.safety import Mode, SafetyConfig, SafetySupervisor
from bar_policy.deploy.signals import StopSignals
from bar_policy.deploy.targets.base import JointState, Target
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.mit import mit_torque

__all__ = ["RunResult", "Runtime", "RuntimeConfig", "TimingStats", "sleep_until"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class RuntimeConfig:
    """Loop settings."""

    control_dt: float = DEFAULT_CONTROL_DT
    """Control period, s (must equal the policy's ``policy_dt``)."""
    duration: float | None = 10.0
    """Run length, s of target time (ticks = duration / control_dt); None runs until a stop or a fault."""
    start_mode: Literal["hold", "policy"] = "hold"
    """``hold``: ramp to the default pose, then the policy. ``policy``: the policy from the first tick."""
    damping_after_fault: float = 1.0
    """After a fault or a stop request, keep commanding damping this long before ending the run, s."""
    realtime: bool = False
    """Pace a synchronous target at wall-clock rate (for the viewer)."""
    spin_s: float = 0.0003
    """Busy-wait this long before each deadline instead of sleeping (sleep overshoots), s."""
    handle_signals: bool = True
    """``run()`` without a ``stop`` installs ``StopSignals`` (SIGINT, SIGTERM, SIGHUP -> the stop path; main
    thread only) for the whole run, the safe ending and the log included."""
    rt_priority: int | None = None
    """Run the loop thread under SCHED_FIFO at this priority (1-99; Linux, needs CAP_SYS_NICE) for the
    length of the run; None keeps the normal scheduler. On a loaded CPU it removes most overruns."""
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    """Safety thresholds."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"RuntimeConfig.control_dt must be > 0 s, got {self.control_dt}")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"RuntimeConfig.duration must be > 0 s or None, got {self.duration}")
        if self.start_mode not in ("hold", "policy"):
            raise ValueError(f"RuntimeConfig.start_mode must be 'hold' or 'policy', got {self.start_mode!r}")
        if self.rt_priority is not None and not 1 <= self.rt_priority <= 99:
            raise ValueError(f"RuntimeConfig.rt_priority must be in 1..99, got {self.rt_priority}")
        if not self.damping_after_fault >= 0:
            raise ValueError(
                f"RuntimeConfig.damping_after_fault must be >= 0 s, got {self.damping_after_fault}"
            )


def sleep_until(deadline: float, spin_s: float = 0.0003) -> None:
    """Wait until ``time.perf_counter() >= deadline``: sleep, then busy-wait the last ``spin_s`` seconds."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        if remaining > spin_s:
            time.sleep(remaining - spin_s)


@dataclass(frozen=True)
class TimingStats:
    """Per-tick timing of a run. Arrays have shape (ticks,), seconds."""

    compute: np.ndarray
    """Host compute per tick: state read -> observation -> ONNX -> command written."""
    infer: np.ndarray
    """ONNX inference alone (NaN in ticks without inference)."""
    jitter: np.ndarray
    """Tick start minus its deadline (0 for an unpaced synchronous target)."""
    overruns: int
    """Ticks that ended after the next deadline."""
    wall: float
    """Wall-clock duration of the loop, s."""
    target_time: float
    """Target-clock duration, s."""
    paced: bool
    """True when ticks were paced against the wall clock."""

    def summary(self) -> dict[str, float]:
        """p50 / p99 / max in ms, counts, rates."""

        def pct(x: np.ndarray, p: float) -> float:
            x = x[np.isfinite(x)]
            return float(np.percentile(x, p) * 1e3) if x.size else float("nan")

        ticks = int(self.compute.size)
        out = {
            "ticks": ticks,
            "compute_p50_ms": pct(self.compute, 50),
            "compute_p99_ms": pct(self.compute, 99),
            "compute_max_ms": pct(self.compute, 100),
            "infer_p50_ms": pct(self.infer, 50),
            "infer_p99_ms": pct(self.infer, 99),
            "overruns": self.overruns,
            "wall_s": self.wall,
            "target_s": self.target_time,
            "rate_hz": ticks / self.wall if self.wall > 0 else float("nan"),
            "realtime_factor": self.target_time / self.wall if self.wall > 0 else float("nan"),
        }
        if self.paced:
            out |= {
                "jitter_p50_ms": pct(np.abs(self.jitter), 50),
                "jitter_p99_ms": pct(np.abs(self.jitter), 99),
                "jitter_max_ms": pct(np.abs(self.jitter), 100),
            }
        return out

    def format(self) -> str:
        """Human-readable table."""
        s = self.summary()
        lines = [
            f"ticks {s['ticks']}  wall {s['wall_s']:.3f} s  target {s['target_s']:.3f} s  "
            f"rate {s['rate_hz']:.1f} Hz  real-time factor {s['realtime_factor']:.1f}x",
            f"compute (state->obs->ONNX->command) p50 {s['compute_p50_ms']:.3f} ms  "
            f"p99 {s['compute_p99_ms']:.3f} ms  max {s['compute_max_ms']:.3f} ms",
            f"ONNX inference p50 {s['infer_p50_ms']:.3f} ms  p99 {s['infer_p99_ms']:.3f} ms",
        ]
        if self.paced:
            lines.append(
                f"jitter p50 {s['jitter_p50_ms']:.3f} ms  p99 {s['jitter_p99_ms']:.3f} ms  "
                f"max {s['jitter_max_ms']:.3f} ms  overruns {s['overruns']}"
            )
        else:
            lines.append("unpaced synchronous target: no jitter, no overruns")
        return "\n".join(lines)


@dataclass(frozen=True)
class RunResult:
    """What a run did."""

    ticks: int
    final_mode: Mode
    transitions: list[dict[str, Any]]
    timing: TimingStats
    end_reason: str
    clip_count: int
    """Joint-ticks whose q_cmd was clipped to a limit."""
    fault_count: int
    log_path: Path | None
    last_state: JointState | None
    """The last state read."""
    action_clip_count: int = 0
    """Action entries clipped to ``+-policy.action_clip``."""
    stop_reason: str | None = None
    """Why a stop was requested (``"SIGTERM received"``), None when none was."""
    safe_stop: str = ""
    """Outcome of ``target.safe_stop``: ``"ok"`` or the error it raised."""
    extras: dict[str, Any] = field(default_factory=dict)


class _RealtimePriority:
    """SCHED_FIFO for the calling thread while inside the block (restored after); logs when not permitted."""

    def __init__(self, priority: int | None) -> None:
        self.priority = priority
        self._previous: tuple[int, int] | None = None

    def __enter__(self) -> _RealtimePriority:
        if self.priority is None:
            return self
        import os

        try:
            prev = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
            self._previous = prev
            log.info("control loop runs under SCHED_FIFO priority %d", self.priority)
        except (AttributeError, OSError) as e:
            log.warning(
                "cannot use SCHED_FIFO priority %d (%s); running with the normal scheduler", self.priority, e
            )
        return self

    def __exit__(self, *exc: object) -> None:
        if self._previous is not None:
            import os

            policy, prio = self._previous
            os.sched_setscheduler(0, policy, os.sched_param(prio))


class Runtime:
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
    ) -> None:
        """Wire a policy, a target and a command source.

        Args:
            policy: a loaded, contract-checked policy.
            target: the joints (started by the caller; the runtime never starts or closes it).
            commands: source of the command terms.
            config: loop settings.
            log_dir: parent directory of the run log; None records nothing.
            log_meta: extra JSON metadata for the run log.
            log_name: suffix of the run directory.
            kinematics: fingertip FK (built for the policy's mode when None).
            on_tick: called after every tick with (tick, run time, runtime) (tests, evaluation).
        """
        self.policy = policy
        self.target = target
        self.commands = commands
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
            raise ValueError(f"command source {commands.describe()} does not feed {missing}")
        self.safety = SafetySupervisor(
            joint_names=robot.joint_names,
            lower=robot.lower,
            upper=robot.upper,
            torque_cap=robot.torque_cap,
            kp=policy.kp,
            kd=policy.kd,
            default_q=policy.hold_pose,
            config=self.config.safety,
        )
        self.kinematics = kinematics or Kinematics(robot.mode)
        self.log_dir = None if log_dir is None else Path(log_dir)
        self.log_meta = dict(log_meta or {})
        self.log_name = log_name
        self.on_tick = on_tick
        self.last_action = np.zeros(policy.n_actions, dtype=np.float32)
        self.action_clip_count = 0
        """Action entries clipped to ``+-policy.action_clip`` over the run."""
        self._action_clip_warned = False
        self.last_state: JointState | None = None
        self.last_commands: dict[str, np.ndarray] = {}
        self._end_t: float | None = None
        """Target time the run started to end (first fault or stop request), s."""
        self._end_reason = ""
        self._stop_reason: str | None = None
        self._pending_stop: str | None = None
        self._cap = robot.torque_cap
        self._runlog: RunLog | None = None
        self._transitions_logged = 0
        self.log_path: Path | None = None

    # -- helpers -------------------------------------------------------------------------------------
    def _fault(self, kind: str, detail: str, t: float) -> None:
        changed = self.safety.fault(kind, detail, t)
        if changed and self._end_t is None:
            self._end_t = t
            self._end_reason = f"fault {kind}: {detail}"

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
            self._end_t = t
            self._end_reason = reason

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
            "joint_names": list(p.robot.joint_names),
            "action_joint_names": list(p.metadata.action_joint_names),
            "mode_names": {m.name: int(m) for m in Mode},
            "policy_dialect": p.metadata.dialect,
            "hold_pose": p.hold_pose.tolist(),
            "runtime_config": asdict(self.config),
        } | self.log_meta

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
                    sf.transition(Mode.HOLD, f"ramp to the default pose over {sf.config.ramp_time:g} s", t)
                else:
                    sf.transition(Mode.POLICY, "start_mode=policy (no ramp)", t)
                    self.last_action[:] = 0.0
        if stop is not None:
            self._stop(stop, t)
        if sf.mode == Mode.HOLD and self._ramp_complete(t):
            sf.transition(Mode.POLICY, "ramp complete", t)
            self.last_action[:] = 0.0

        cmds = self.commands(t)
        self.last_commands = cmds
        left, right = self.kinematics.fingertips(state.q)
        inputs = {
            "joint_pos": state.q,
            "joint_vel": state.dq,
            "actions": self.last_action,
            "fingertip_pos_left": left,
            "fingertip_pos_right": right,
            **cmds,
        }
        obs = self.policy.obs_manager.compute(inputs)
        action = None
        q_policy = None
        infer = math.nan
        n_action_clipped = 0
        if sf.mode == Mode.POLICY:
            t_inf = time.perf_counter()
            action = self.policy(obs)
            infer = time.perf_counter() - t_inf
            bad = sf.check_action(action)
            if bad is not None:
                self._fault(*bad, t)
            else:
                used = self._clip_action(action, t)
                n_action_clipped = int(np.count_nonzero(used != action))
                q_policy = self.policy.q_command(used)
                self.last_action = used
        cmd = sf.command(t, q_policy)
        sat = sf.check_torque(cmd, state, self.config.control_dt)
        demand = sf.last_demand
        if sat is not None:
            self._fault(*sat, t)
            cmd = sf.command(t, q_policy)
            demand = mit_torque(cmd, state.q, state.dq)
        self.target.write_command(cmd)
        compute = time.perf_counter() - t_start
        return {
            "t": t,
            "mode": int(sf.mode),
            "q": state.q,
            "dq": state.dq,
            "tau": state.tau,
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
            **cmds,
        }

    def _clip_action(self, action: np.ndarray, t: float) -> np.ndarray:
        """``clip(action, -c, c)`` with c = ``policy.action_clip`` (float32); clipped entries are counted."""
        c = self.policy.action_clip
        if c is None:
            return action
        used = np.minimum(np.maximum(action, np.float32(-c)), np.float32(c))
        if (used != action).any():
            n = int(np.count_nonzero(used != action))
            self.action_clip_count += n
            if not self._action_clip_warned:
                self._action_clip_warned = True
                log.warning(
                    "policy action outside +-%g at t=%.3f s (indices %s); clipped as in training "
                    "(further ones counted)",
                    c,
                    t,
                    np.flatnonzero(used != action).tolist(),
                )
        return used

    def _ramp_complete(self, t: float) -> bool:
        sf = self.safety
        return sf.config.ramp_time <= 0 or (t - sf.ramp_t0) >= sf.config.ramp_time - 1e-9

    # -- the loop ------------------------------------------------------------------------------------
    def run(self, stop: StopSignals | None = None) -> RunResult:
        """Run until the duration, a fault or a stop request (+ ``damping_after_fault``), or an exception.

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

        Returns:
            The run directory, or None without ``log_dir``.

        Raises:
            LogDirError: the run directory cannot be created or written.
        """
        if self._runlog is None and self.log_dir is not None:
            self._runlog = self._make_log()
        return None if self._runlog is None else self._runlog.path

    def close_unstarted(self, reason: str) -> None:
        """Close a log opened by ``open_log`` for a run that never started (``end_reason`` = ``reason``)."""
        if self._runlog is not None and not self._runlog.closed:
            self._runlog.close(end_reason=reason, transitions=[], fault_count=0)
            self.log_path = self._runlog.path / "log.npz"

    def _make_log(self) -> RunLog:
        om = self.policy.obs_manager
        fields = log_fields(self.policy.robot.num_joints, self.policy.n_actions, om.size, self.commands.names)
        return RunLog(
            self.log_dir,
            fields,
            self._meta(),
            name=self.log_name,
            labels={"mode": {int(m): m.name for m in Mode}},
        )

    def _run(self, stop: StopSignals) -> RunResult:
        cfg = self.config
        dt = cfg.control_dt
        n_ticks = None if cfg.duration is None else max(round(cfg.duration / dt), 1)
        paced = not self.target.synchronous or cfg.realtime
        self.open_log()
        runlog = self._runlog
        compute, infer, jitter = [], [], []
        overruns = 0
        k = 0
        end_reason = "duration reached"
        t0_target = self.target.now()
        wall0 = time.perf_counter()
        deadline = wall0
        error: BaseException | None = None
        try:
            with _RealtimePriority(cfg.rt_priority):
                while n_ticks is None or k < n_ticks:
                    if paced:
                        sleep_until(deadline, cfg.spin_s)
                    start = time.perf_counter()
                    lateness = start - deadline if paced else 0.0
                    t = self.target.now() - t0_target if not self.target.synchronous else k * dt
                    if stop.requested:
                        self.request_stop(stop.reason)
                    rec = self._tick(k, t, self._pending_stop)
                    end = time.perf_counter()
                    overran = False
                    if paced:
                        deadline += dt
                        if end > deadline:
                            overran = True
                            overruns += 1
                            missed = math.ceil((end - deadline) / dt)
                            deadline += missed * dt  # skip the missed deadlines, keep the grid
                    rec["jitter"] = lateness
                    rec["overrun"] = overran
                    rec["wall"] = start - wall0
                    compute.append(rec["compute"])
                    infer.append(rec["infer"])
                    jitter.append(lateness)
                    if runlog is not None:
                        runlog.append(rec)
                    if self.target.synchronous:
                        self.target.advance(dt)
                    else:
                        ov = self.safety.note_overrun(overran)
                        if ov is not None:
                            self._fault(*ov, t)
                    self._log_transitions()
                    if self.on_tick is not None:
                        self.on_tick(k, t, self)
                    k += 1
                    if self._end_t is not None and t - self._end_t >= cfg.damping_after_fault - 1e-9:
                        end_reason = self._end_reason
                        break
        except BaseException as e:
            error = e
            end_reason = f"exception {type(e).__name__}: {e}"
            raise
        finally:
            wall = time.perf_counter() - wall0  # the loop alone, without the safe ending
            t_end = self.target.now() - t0_target
            safe_stop = self._safe_end(end_reason, t_end)
            self._log_transitions()
            timing = TimingStats(
                compute=np.asarray(compute),
                infer=np.asarray(infer),
                jitter=np.asarray(jitter),
                overruns=overruns,
                wall=wall,
                target_time=k * dt if self.target.synchronous else t_end,
                paced=paced,
            )
            log_path = None
            if runlog is not None:
                try:
                    log_path = runlog.close(
                        end_reason=end_reason,
                        target_metadata=self._target_metadata(),
                        stop_reason=self._stop_reason,
                        stop_signal=stop.signal_name,
                        stop_signals_received=stop.count,
                        safe_stop=safe_stop,
                        exception=None if error is None else f"{type(error).__name__}: {error}",
                        transitions=[tr.to_dict() for tr in self.safety.transitions],
                        timing=timing.summary(),
                        clip_count=self.safety.clip_count,
                        action_clip_count=self.action_clip_count,
                        fault_count=self.safety.fault_count,
                        command_outside_workspace=self.commands.outside_count,
                    )
                except Exception:
                    log.exception("could not write the run log in %s", runlog.path)
                    if error is None:
                        raise
            self.log_path = log_path
        return RunResult(
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
        )

    def _target_metadata(self) -> dict[str, Any]:
        try:
            return dict(self.target.run_metadata())
        except Exception as e:  # never lose the log for a description
            return {"error": f"{type(e).__name__}: {e}"}

    def _safe_end(self, reason: str, t: float) -> str:
        """DAMPING (logged with the reason), then the target's safe stop; errors here are logged only.

        Returns:
            ``"ok"``, or the error ``target.safe_stop`` raised.
        """
        sf = self.safety
        if sf.mode in (Mode.HOLD, Mode.POLICY, Mode.ZERO_TORQUE):
            level = logging.INFO if reason == "duration reached" else logging.WARNING
            sf.transition(Mode.DAMPING, f"run ended: {reason}", t, level=level)
        try:
            self.target.safe_stop(sf.captured_q, sf.config.damping_kd)
        except Exception as e:
            log.exception("safe_stop of %s failed", type(self.target).__name__)
            return f"failed: {type(e).__name__}: {e}"
        return "ok"
