"""Controller modes and the safety state machine between the policy and the joints.

Modes (the MIT surface of the seed; which fields are nonzero):

- ``ZERO_TORQUE``: everything 0, "alive but inert". The state before the first reading.
- ``DAMPING``: Kp = 0, Kd > 0, q_cmd = the q captured on entry: the compliant fail-safe. Every fault lands
  here, and it latches: the supervisor never leaves DAMPING by itself.
- ``HOLD``: PD from the pose at entry to the default pose over ``ramp_time`` seconds, with a soft start of
  the gains (Kp from 0 to the policy's Kp, Kd from the damping Kd to the policy's Kd, both on a smoothstep),
  then holding the default pose. The runtime also enters HOLD from POLICY when the task's commands end (a
  motion clip's last frame): then the target is the pose the command source names, the ramp its own, and
  the gains stay at the policy's (no soft start from POLICY: the arms are carried, not dropped).
- ``POLICY``: q_cmd = default + action_scale * action, clipped to the joint limits (every clipped joint is
  counted, and the first clip of each joint is logged), the file's Kp / Kd, dq_cmd = 0, tau_ff = 0.

Faults (each moves HOLD or POLICY to DAMPING with its reason; the first occurrence of a fault kind while
already in DAMPING is logged too): non-finite state or action, a joint beyond its limit by more than
``limit_margin``, a joint at its torque cap (the demand beyond it, the motor's reported torque near it) for
longer than ``saturation_time``, a state older than
``stale_timeout``, ``max_overruns`` consecutive loop overruns, hardware faults reported by the target, and a
policy that keeps asking far beyond its action range (``action_out_of_range``: some raw action entry at
``|a| >= action_range_factor * bound`` for longer than ``action_range_time``, bound = the policy's action
clip, else 1 action unit; with the defaults |a| >= 4x the clip for more than 0.2 s, i.e. the 11th
consecutive tick at 50 Hz, 0.2 s after the first).
A stop request (SIGINT / SIGTERM / SIGHUP, see ``runtime``) also ends in DAMPING, but is not a fault. Every
transition is logged (python ``logging``) and kept in ``transitions`` for the run log.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from bar_policy.deploy.safety_checks import DEFAULT_REACH_MARGIN, CapDwell, _smoothstep, check_action_scale
from bar_policy.deploy.safety_config import Mode, SafetyConfig, Transition
from bar_policy.deploy.targets.base import JointState
from bar_policy.robot.mit import MitCommand, mit_torque

__all__ = [
    "DEFAULT_REACH_MARGIN",
    "CapDwell",
    "Mode",
    "SafetyConfig",
    "SafetySupervisor",
    "Transition",
    "check_action_scale",
]

log = logging.getLogger(__name__)


@dataclass
class SafetySupervisor:
    """Decides the MIT command of every tick from the mode, the state and (in POLICY) the policy's q_cmd.

    Arrays have shape ``(num_joints,)`` in canonical order.
    """

    joint_names: tuple[str, ...]
    lower: np.ndarray
    """Joint lower limits, rad."""
    upper: np.ndarray
    """Joint upper limits, rad."""
    torque_cap: np.ndarray
    """Firmware torque cap, N*m."""
    kp: np.ndarray
    """Kp of HOLD (after the ramp) and POLICY, N*m/rad."""
    kd: np.ndarray
    """Kd of HOLD (after the ramp) and POLICY, N*m*s/rad."""
    default_q: np.ndarray
    """Default pose (HOLD target), rad."""
    config: SafetyConfig = field(default_factory=SafetyConfig)
    mode: Mode = Mode.ZERO_TORQUE
    transitions: list[Transition] = field(default_factory=list)
    clip_count: int = 0
    """Joint-ticks whose q_cmd was clipped to a limit, over the run."""
    fault_count: int = 0
    """Faults detected (including those while already in DAMPING)."""
    tick: int = 0
    """Current control tick (set by the runtime)."""

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for name in ("lower", "upper", "torque_cap", "kp", "kd", "default_q"):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            if arr.shape != (n,):
                raise ValueError(f"SafetySupervisor.{name} has shape {arr.shape}, expected ({n},)")
            setattr(self, name, arr)
        self._captured_q = np.zeros(n)
        self._last_finite_q: np.ndarray | None = None
        self._ramp_q0 = self.default_q.copy()
        self._ramp_t0 = 0.0
        self._ramp_target = self.default_q.copy()
        self._ramp_T = self.config.ramp_time
        self._gain0 = 0.0
        self._dwell = CapDwell(
            self.config.saturation_fraction * self.torque_cap,
            self.config.saturation_time,
            self.config.saturation_reported_fraction * self.torque_cap,
        )
        self.last_demand = np.zeros(n)
        """Unclipped MIT torque of the last command checked by ``check_torque``, N*m."""
        self._overruns = 0
        self._action_dwell: CapDwell | None = None
        self._clipped_joints: set[int] = set()
        self._fault_kinds_logged: set[str] = set()
        self.last_clipped = 0
        """Joints clipped in the last POLICY command."""
        self._now = 0.0

    # -- transitions ---------------------------------------------------------------------------------
    def transition(
        self,
        dst: Mode,
        reason: str,
        t: float,
        *,
        level: int = logging.INFO,
        hold_target: np.ndarray | None = None,
        hold_ramp: float | None = None,
    ) -> None:
        """Change mode (no-op when already there), capturing what the new mode needs, and log it.

        Args:
            dst: the new mode.
            reason: why (kept in ``transitions`` and the run log).
            t: target time, s.
            level: logging level of the message (faults use WARNING).
            hold_target: HOLD only: the pose to ramp to, rad, shape (n,) (default: ``default_q``).
            hold_ramp: HOLD only: the ramp's duration, s (default: ``config.ramp_time``).
        """
        if dst == self.mode:
            return
        src = self.mode
        if dst == Mode.DAMPING:
            self._captured_q = (
                self._last_finite_q.copy()
                if self._last_finite_q is not None
                else np.zeros(len(self.joint_names))
            )
        elif dst == Mode.HOLD:
            if self._last_finite_q is None:
                raise RuntimeError("HOLD needs a finite joint state first")
            target = self.default_q if hold_target is None else np.asarray(hold_target, dtype=np.float64)
            if target.shape != self.default_q.shape or not np.isfinite(target).all():
                raise ValueError(f"HOLD target must be finite with shape {self.default_q.shape}")
            self._ramp_q0 = self._last_finite_q.copy()
            self._ramp_t0 = t
            self._ramp_target = target.copy()
            self._ramp_T = self.config.ramp_time if hold_ramp is None else float(hold_ramp)
            self._gain0 = 1.0 if src == Mode.POLICY else 0.0  # no soft start when the policy had full gains
            self._dwell.reset()
        elif dst == Mode.POLICY:
            self._dwell.reset()
            self._action_dwell = None
        self.mode = dst
        tr = Transition(t=t, tick=self.tick, src=src, dst=dst, reason=reason)
        self.transitions.append(tr)
        log.log(level, "mode %s -> %s at t=%.3f s (tick %d): %s", src.name, dst.name, t, self.tick, reason)

    def fault(self, kind: str, detail: str, t: float) -> bool:
        """Report a fault: HOLD / POLICY go to DAMPING. Returns True when it changed the mode."""
        self.fault_count += 1
        reason = f"fault {kind}: {detail}"
        if self.mode in (Mode.HOLD, Mode.POLICY):
            self.transition(Mode.DAMPING, reason, t, level=logging.WARNING)
            self._fault_kinds_logged.add(kind)
            return True
        if kind not in self._fault_kinds_logged:
            self._fault_kinds_logged.add(kind)
            log.warning("in %s at t=%.3f s (tick %d): %s", self.mode.name, t, self.tick, reason)
        return False

    @property
    def captured_q(self) -> np.ndarray:
        """q_cmd of DAMPING: the last finite q at entry (zeros before any finite reading), rad."""
        return self._captured_q.copy()

    @property
    def ramp_t0(self) -> float:
        """Target time the HOLD ramp started, s."""
        return self._ramp_t0

    @property
    def ramp_done(self) -> bool:
        """True once HOLD has reached its target pose with the full gains (at the last command's time)."""
        return self.ramp_complete(self._now)

    def ramp_complete(self, t: float) -> bool:
        """True when HOLD's ramp is over at target time ``t`` (s)."""
        return self.mode == Mode.HOLD and self._ramp_alpha(t) >= 1.0 - 1e-9 / max(self._ramp_T, 1e-9)

    @property
    def hold_target(self) -> np.ndarray:
        """Where HOLD ramps to (``default_q`` unless the runtime entered HOLD with a target), rad."""
        return self._ramp_target.copy()

    def _ramp_alpha(self, t: float) -> float:
        T = self._ramp_T
        return 1.0 if T <= 0 else (t - self._ramp_t0) / T

    # -- checks --------------------------------------------------------------------------------------
    def check_state(self, state: JointState, now: float) -> tuple[str, str] | None:
        """The first fault in a state reading, as ``(kind, detail)``, or None. Remembers the last finite q."""
        q, dq = state.q, state.dq
        finite_q = bool(np.isfinite(q).all())
        if finite_q:
            self._last_finite_q = np.array(q, dtype=np.float64)
        if state.faults:
            return "target", f"target reports faults {list(state.faults)}"
        if not (finite_q and np.isfinite(dq).all()):
            bad = np.flatnonzero(~(np.isfinite(q) & np.isfinite(dq)))
            return "nonfinite_state", f"non-finite q/dq at joints {[self.joint_names[i] for i in bad]}"
        age = now - state.stamp
        if not age <= self.config.stale_timeout:
            return (
                "stale_state",
                f"state is {age * 1e3:.1f} ms old (timeout {self.config.stale_timeout * 1e3:g} ms)",
            )
        m = self.config.limit_margin
        if (q < self.lower - m).any() or (q > self.upper + m).any():
            beyond = np.flatnonzero((q < self.lower - m) | (q > self.upper + m))
            items = ", ".join(
                f"{self.joint_names[i]} q={q[i]:.3f} rad not in [{self.lower[i]:.3f}, {self.upper[i]:.3f}]"
                for i in beyond
            )
            return "joint_limit", f"beyond the limit margin {m:g} rad: {items}"
        return None

    def check_action(self, action: np.ndarray) -> tuple[str, str] | None:
        """A fault for a non-finite action (shape (n_actions,)), or None."""
        if np.isfinite(action).all():
            return None
        bad = np.flatnonzero(~np.isfinite(action))
        if bad.size:
            return "nonfinite_action", f"policy output non-finite at action indices {bad.tolist()}"
        return None

    def check_action_range(
        self, action: np.ndarray, bound: float, names: tuple[str, ...], dt: float
    ) -> tuple[str, str] | None:
        """Track time far beyond the action range; a fault when any entry has been there too long.

        Args:
            action: the raw policy output, action units, shape (n_actions,).
            bound: the action clip, action units (the limit is ``config.action_range_factor * bound``).
            names: joint name of each action entry.
            dt: control period, s.

        Returns:
            ``("action_out_of_range", detail)`` once some entry has stayed at ``|a| >= limit`` for longer than
            ``config.action_range_time``, else None.
        """
        factor = self.config.action_range_factor
        if factor <= 0:
            return None
        limit = factor * bound
        a = np.asarray(action, dtype=np.float64)
        if self._action_dwell is None or self._action_dwell.level.shape != a.shape:
            self._action_dwell = CapDwell(np.full(a.shape, limit), self.config.action_range_time)
        over = self._action_dwell.update(a, dt)
        if over.size:
            items = ", ".join(f"{names[i]} ({a[i]:.3g})" for i in over)
            return (
                "action_out_of_range",
                f"raw action beyond {factor:g} x the clip bound {bound:g} (|a| >= {limit:g}) for > "
                f"{self.config.action_range_time:g} s: {items}",
            )
        return None

    def check_torque(
        self, cmd: MitCommand, state: JointState, dt: float, *, use_reported: bool = True
    ) -> tuple[str, str] | None:
        """Track time at the torque cap; a fault when any joint has been there longer than allowed.

        The demand is the unclipped MIT torque of ``cmd`` at the measured state, N*m; a joint is at the cap
        while it reaches ``saturation_fraction`` of the cap and the torque its motor reports (``state.tau``)
        reaches ``saturation_reported_fraction`` of it (``quality.metrics.at_cap``). ``use_reported`` False:
        the demand alone (a target that applies no command reports no torque: a dry run's would-be
        saturation).
        """
        signed = mit_torque(cmd, state.q, state.dq)
        self.last_demand = signed
        demand = np.abs(signed)
        over = self._dwell.update(signed, dt, np.asarray(state.tau, dtype=float) if use_reported else None)
        if over.size:
            items = ", ".join(
                f"{self.joint_names[i]} ({demand[i]:.2f} N*m asked, {abs(float(state.tau[i])):.2f} reported, "
                f"cap {self.torque_cap[i]:g})"
                for i in over
            )
            return "torque_saturation", f"torque at the cap for > {self.config.saturation_time:g} s: {items}"
        return None

    def note_overrun(self, overran: bool) -> tuple[str, str] | None:
        """Count consecutive overruns; a fault at ``max_overruns`` in a row."""
        self._overruns = self._overruns + 1 if overran else 0
        n = self.config.max_overruns
        if n and self._overruns >= n:
            self._overruns = 0
            return "overrun", f"{n} consecutive loop overruns (the tick took longer than its period)"
        return None

    # -- commands ------------------------------------------------------------------------------------
    def command(self, t: float, q_policy: np.ndarray | None = None) -> MitCommand:
        """The MIT command of the current mode at target time ``t`` (s).

        Args:
            t: target time, s (drives the HOLD ramp).
            q_policy: unclipped q_cmd from the policy, rad, shape (num_joints,); required in POLICY.
        """
        self._now = t
        self.last_clipped = 0
        n = len(self.joint_names)
        if self.mode == Mode.ZERO_TORQUE:
            return MitCommand.zero_torque(n)
        if self.mode == Mode.DAMPING:
            return MitCommand.damping(self._captured_q, self.config.damping_kd)
        if self.mode == Mode.HOLD:
            s = _smoothstep(self._ramp_alpha(t))
            q = self._ramp_q0 + s * (self._ramp_target - self._ramp_q0)
            g = self._gain0 + (1.0 - self._gain0) * s
            kd0 = self.config.damping_kd
            return MitCommand.position(q, g * self.kp, kd0 + g * (self.kd - kd0))
        if q_policy is None:
            raise ValueError("POLICY mode needs q_policy")
        q = np.minimum(np.maximum(q_policy, self.lower), self.upper)
        if (q != q_policy).any():
            clipped = np.flatnonzero(q != q_policy)
            self.last_clipped = int(clipped.size)
            self.clip_count += int(clipped.size)
            for i in clipped:
                if i not in self._clipped_joints:
                    self._clipped_joints.add(int(i))
                    log.warning(
                        "q_cmd of %s clipped to its limit: %.4f -> %.4f rad (t=%.3f s; further ones counted)",
                        self.joint_names[i],
                        q_policy[i],
                        q[i],
                        t,
                    )
        return MitCommand(q, np.zeros(n), self.kp.copy(), self.kd.copy(), np.zeros(n))
