"""The control loop's settings (``RuntimeConfig``) and what a run did (``RunResult``).

Exit status of a run (``RunResult.exit_status``; ``bar-deploy`` returns it):

- ``EXIT_OK`` (0): ran to the end, or stopped on request, and every joint answered the stop;
- ``EXIT_FAULT`` (1): a fault or an error during the run (the joints were damped and stopped);
- ``EXIT_REFUSED`` (2): refused before anything moved (bad arguments, policy or target; ``bar-deploy``);
- ``EXIT_STOP_UNCONFIRMED`` (3): the safe stop was not confirmed: some joint did not answer the damping or
  the stop frames, or the safe stop raised (it takes precedence over 1: the motors may still be enabled).

The ``end:`` line (``RunResult.end_line``) names the end reason (the first fault whenever one occurred), the
final mode, both clip counts, the safe stop's outcome and the later faults, if any.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bar_policy.deploy.policy import DEFAULT_CONTROL_DT
from bar_policy.deploy.safety import DEFAULT_REACH_MARGIN, Mode, SafetyConfig
from bar_policy.deploy.targets.base import JointState
from bar_policy.deploy.timing import TimingStats

__all__ = [
    "EXIT_FAULT",
    "EXIT_OK",
    "EXIT_REFUSED",
    "EXIT_STOP_UNCONFIRMED",
    "RunResult",
    "RuntimeConfig",
]

EXIT_OK = 0
"""Exit status: ran to the end or stopped on request; the stop was confirmed by every joint."""
EXIT_FAULT = 1
"""Exit status: a fault or an error during the run (damped, then stopped, the stop confirmed)."""
EXIT_REFUSED = 2
"""Exit status: refused before anything moved."""
EXIT_STOP_UNCONFIRMED = 3
"""Exit status: the safe stop was not confirmed (a joint did not answer, or ``safe_stop`` raised)."""


HAND_LOAD_KINDS = ("estimate", "tare", "off")
"""``RuntimeConfig.hand_load``: ``estimate`` fits the hands' loads online and adds their gravity torque as
``tau_ff`` (``deploy.hand_load``); ``tare`` fits them while the command source holds the arms still and
free (``CommandSource.still_s``: the piano's count-in), then keeps that estimate; ``off``: none."""


@dataclass(frozen=True, kw_only=True)
class RuntimeConfig:
    """Loop settings."""

    control_dt: float = DEFAULT_CONTROL_DT
    """Control period, s (must equal the policy's ``policy_dt``)."""
    duration: float | None = 10.0
    """Run length, s; None runs until a stop or a fault. Wall-clock time when the loop is paced (an
    asynchronous target, or ``realtime``): the loop ends at the first deadline at or after it, ticks that
    ran late skip deadlines (``TimingStats.skipped``); else target time (ticks = duration / control_dt)."""
    start_mode: Literal["hold", "policy"] = "hold"
    """``hold``: ramp to the default pose, then the policy. ``policy``: the policy from the first tick."""
    damping_after_fault: float = 1.0
    """After a fault or a stop request, keep commanding damping this long before ending the run, s."""
    end_hold: float = 1.0
    """After the command source's end (a motion clip's last frame), HOLD its end pose this long before the
    run ends as completed, s (the pose ramps over the first half)."""
    stop_damping: str = "gravity"
    """The damping of the fault and end stops (``deploy.gravity``): ``gravity`` adds the model's gravity
    torque at the measured q as ``tau_ff`` (within the caps), ``plain`` is Kd alone."""
    hand_load: str | None = None
    """Hand-load compensation in POLICY (and the end's HOLD), one of ``HAND_LOAD_KINDS``; None: the command
    source's (``CommandSource.hand_load``: tracking ``estimate``, the piano ``tare``, reach ``off``)."""
    load_inertia: bool | None = None
    """Feed the hand-load fit's masses' inertia forward in POLICY from a reference arm
    (``deploy.load_inertia``; needs the fit); None: the command source's (``CommandSource.load_inertia``:
    the piano on, else off)."""
    start_tare_s: float = 1.0
    """With the hand-load ``tare`` and a start through HOLD (``start_mode="hold"``): how long HOLD holds its
    target still after the ramp while the fit tares and feeds its estimate forward, s, before POLICY and
    the source's still start (which fits on from there). A loaded arm sags onto what lies under the
    start pose (the piano's keys) during the ramp; this lifts it off before the count-in (0: the count-in
    alone, which reads what the keys do not carry; docs/robustness.md, "The piano's tare")."""
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
    action_reach_margin: float = DEFAULT_REACH_MARGIN
    """The policy's reach ``default +- action_scale * action_clip`` may go this far beyond a joint's range
    before the runtime refuses the policy, rad (``action_path.check_action_scale``)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"RuntimeConfig.control_dt must be > 0 s, got {self.control_dt}")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0):
            raise ValueError(f"RuntimeConfig.duration must be > 0 s or None, got {self.duration}")
        if self.stop_damping not in ("gravity", "plain"):
            raise ValueError(
                f"RuntimeConfig.stop_damping must be 'gravity' or 'plain', got {self.stop_damping!r}"
            )
        if self.hand_load is not None and self.hand_load not in HAND_LOAD_KINDS:
            raise ValueError(
                f"RuntimeConfig.hand_load must be one of {HAND_LOAD_KINDS} or None, got {self.hand_load!r}"
            )
        if self.start_mode not in ("hold", "policy"):
            raise ValueError(f"RuntimeConfig.start_mode must be 'hold' or 'policy', got {self.start_mode!r}")
        if self.rt_priority is not None and not 1 <= self.rt_priority <= 99:
            raise ValueError(f"RuntimeConfig.rt_priority must be in 1..99, got {self.rt_priority}")
        for name in ("damping_after_fault", "end_hold", "action_reach_margin", "start_tare_s"):
            v = getattr(self, name)
            if not v >= 0:
                raise ValueError(f"RuntimeConfig.{name} must be >= 0 s, got {v}")


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
    """Outcome of ``target.safe_stop``: ``StopReport.summary()`` (``"stop confirmed (...)"``, or the joints
    that did not answer), or ``"failed: ..."`` with the error it raised."""
    stop_confirmed: bool = True
    """True when every joint answered the damping and the stop frames of the safe stop."""
    stop_unconfirmed: tuple[str, ...] = ()
    """Joints that did not answer the damping or the stop frames (empty when confirmed or when it raised)."""
    completed: bool = False
    """True when the run ended because the commands finished (a motion clip played to its end)."""
    quality: dict[str, Any] = field(default_factory=dict)
    """Safety and smoothness of the POLICY ticks: ``{"episode": EpisodeQuality dict, "summary": ...}``."""
    extras: dict[str, Any] = field(default_factory=dict)
    action_count: int = 0
    """Raw action entries the policy produced (POLICY ticks x n_actions), the denominator of the clips."""
    later_faults: tuple[str, ...] = ()
    """The distinct faults after the first (which the end reason names), in the order they came."""
    hand_load: dict[str, Any] = field(default_factory=dict)
    """The hand-load compensation's record at the end (``Runtime.hand_load_record``: its kind and, when on,
    the fit's record: the last estimate per hand ``mass_kg``, the arm's ``motion_rad`` while fitting)."""

    @property
    def exit_status(self) -> int:
        """The exit status: 3 stop not confirmed, else 1 after a fault, else 0 (module docstring)."""
        if not self.stop_confirmed:
            return EXIT_STOP_UNCONFIRMED
        return EXIT_FAULT if self.fault_count else EXIT_OK

    def _later_text(self, shown: int = 3) -> str:
        """The first ``shown`` later faults, then how many more (all of them are in the run log)."""
        text = "; ".join(self.later_faults[:shown])
        more = len(self.later_faults) - shown
        return f"{text}; and {more} more (run.json: later_faults)" if more > 0 else text

    def end_line(self) -> str:
        """The ``end:`` line: reason, final mode, q_cmd and action clip counts, the safe stop's outcome."""
        return (
            f"end: {self.end_reason}; final mode {self.final_mode.name}; "
            f"q_cmd clipped {self.clip_count} joint-ticks; "
            f"actions clipped {self.action_clip_count} of {self.action_count} entries; "
            f"safe stop: {self.safe_stop}"
            + (f"; later faults: {self._later_text()}" if self.later_faults else "")
        )
