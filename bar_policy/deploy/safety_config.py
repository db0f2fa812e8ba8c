"""Controller modes, the safety supervisor's thresholds and its mode transitions (``deploy.safety``)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from bar_policy.quality.metrics import REPORTED_CAP_FRACTION

__all__ = ["Mode", "SafetyConfig", "Transition"]


class Mode(enum.IntEnum):
    """Controller modes, in the order of the start-up sequence."""

    ZERO_TORQUE = 0
    DAMPING = 1
    HOLD = 2
    POLICY = 3


@dataclass(frozen=True, kw_only=True)
class SafetyConfig:
    """Thresholds of the safety supervisor."""

    damping_kd: float = 1.0
    """Kd of the DAMPING mode, N*m*s/rad (Humanoid Control's damping-controller default)."""
    ramp_time: float = 3.0
    """Duration of the HOLD ramp from the current pose to the default pose, s (0 = jump)."""
    limit_margin: float = 0.1
    """A measured joint further than this beyond its limit is a fault, rad."""
    saturation_fraction: float = 1.0
    """A joint is at the cap when ``|unclipped MIT torque| >= fraction * torque_cap`` (and its motor reports
    ``saturation_reported_fraction`` of the cap)."""
    saturation_reported_fraction: float = REPORTED_CAP_FRACTION
    """...and while the torque the motor reports (``JointState.tau``) is at least this share of the cap,
    dimensionless, in [0, 1] (0: the demand alone). The demand is the command sent now at the state just
    read; under latency the motor applies an older one, and a lead over the cap while the motor delivers a
    fraction of it is not a saturated joint (``quality.metrics.REPORTED_CAP_FRACTION``)."""
    saturation_time: float = 0.5
    """Time a joint may stay at its torque cap before it is a fault, s."""
    stale_timeout: float = 0.1
    """A state older than this (target clock) is stale, s (Humanoid Control: 100 ms)."""
    max_overruns: int = 5
    """Consecutive loop overruns that make a fault (0 disables the check)."""
    action_range_factor: float = 4.0
    """A raw action entry is far out of range at ``|a| >= factor * bound`` (bound = the policy's action clip,
    else 1 action unit), dimensionless; 0 disables the ``action_out_of_range`` fault."""
    action_range_time: float = 0.2
    """Time an action entry may stay far out of range (unbroken, same rule as ``CapDwell``) before the fault
    ``action_out_of_range``, s."""

    def __post_init__(self) -> None:
        for name in (
            "ramp_time",
            "limit_margin",
            "saturation_time",
            "stale_timeout",
            "action_range_factor",
            "action_range_time",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"SafetyConfig.{name} must be a finite number >= 0, got {v!r}")
        if not (math.isfinite(self.damping_kd) and self.damping_kd > 0):
            raise ValueError(f"SafetyConfig.damping_kd must be > 0 N*m*s/rad, got {self.damping_kd!r}")
        if not 0 < self.saturation_fraction <= 1:
            raise ValueError(
                f"SafetyConfig.saturation_fraction must be in (0, 1], got {self.saturation_fraction}"
            )
        if not 0 <= self.saturation_reported_fraction <= 1:
            raise ValueError(
                "SafetyConfig.saturation_reported_fraction must be in [0, 1], got "
                f"{self.saturation_reported_fraction}"
            )
        if self.max_overruns < 0:
            raise ValueError(f"SafetyConfig.max_overruns must be >= 0, got {self.max_overruns}")


@dataclass(frozen=True)
class Transition:
    """One mode change."""

    t: float
    """Target time of the change, s."""
    tick: int
    """Control tick of the change."""
    src: Mode
    dst: Mode
    reason: str

    def to_dict(self) -> dict[str, object]:
        """JSON form for the run log."""
        return {
            "t": self.t,
            "tick": self.tick,
            "from": self.src.name,
            "to": self.dst.name,
            "reason": self.reason,
        }
