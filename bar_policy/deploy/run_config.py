"""The control loop's settings (``RuntimeConfig``) and what a run did (``RunResult``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bar_policy.deploy.policy import DEFAULT_CONTROL_DT
from bar_policy.deploy.safety import Mode, SafetyConfig
from bar_policy.deploy.targets.base import JointState
from bar_policy.deploy.timing import TimingStats

__all__ = ["RunResult", "RuntimeConfig"]


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
    end_hold: float = 1.0
    """After the command source's end (a motion clip's last frame), HOLD its end pose this long before the
    run ends as completed, s (the pose ramps over the first half)."""
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
        for name in ("damping_after_fault", "end_hold"):
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
    """Outcome of ``target.safe_stop``: ``"ok"`` or the error it raised."""
    completed: bool = False
    """True when the run ended because the commands finished (a motion clip played to its end)."""
    quality: dict[str, Any] = field(default_factory=dict)
    """Safety and smoothness of the POLICY ticks: ``{"episode": EpisodeQuality dict, "summary": ...}``."""
    extras: dict[str, Any] = field(default_factory=dict)
