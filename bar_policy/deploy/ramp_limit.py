"""The shortest HOLD ramp the real target accepts, derived from the torque caps, Kp and the start-up error.

Derivation. HOLD moves the command from the pose at entry ``q0`` to the hold pose ``h`` along a smoothstep,
``q_cmd(t) = q0 + s(t / T) (h - q0)`` with ``s(x) = 3x^2 - 2x^3`` (``safety_checks._smoothstep``), and ramps
Kp with the same ``s`` from 0 (``SafetySupervisor.command``). The steepest slope of ``s`` is
``s'(1/2) = 1.5``, so between two control ticks (period ``dt``) a joint's command moves by at most

    dq_tick = 1.5 * |h - q0| * dt / T.

A joint that followed the previous command is pushed by the PD term ``Kp * dq_tick`` at most (the
smoothstep gain ``s <= 1`` only lowers it). Keeping that push within the firmware torque cap, for every
joint, with the largest start-up error the real target can start from,

    Kp_j * 1.5 * E_j * dt / T <= cap_j   =>   T >= T_min = max_j 1.5 * E_j * Kp_j * dt / cap_j,

where ``E_j = max(upper_j + m - h_j, h_j - lower_j + m)`` is the farthest a joint can be from its hold pose
when the start-up accepts it (``RobstrideGroup.activate`` refuses a joint more than ``m =
START_LIMIT_MARGIN`` beyond its range). A step (``--ramp-time 0`` or ``--start policy``) puts the whole
``E_j`` into one tick: ``Kp * E`` = 50 x 1.49 = 74.5 N*m asked of a 4 N*m wrist, i.e. the cap, for as long
as the arm takes to get there (the snap of the arms).

For ``checkpoints/lite_reach_arms.onnx`` (Kp 50 on every joint, dt 0.02 s) the wrist yaw decides it:
range [-1.571, 1.571] rad, hold -1.2 rad, cap 4 N*m: E = 1.571 + 0.3 + 1.2 = 3.071 rad, T_min =
1.5 x 3.071 x 50 x 0.02 / 4 = 1.152 s (the default ramp, 3 s, is above it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["START_LIMIT_MARGIN", "UNSAFE_FLAG", "RampLimit", "min_ramp_time", "ramp_limit"]

START_LIMIT_MARGIN = 0.3
"""How far beyond its range a joint may be at the real target's start-up before activation refuses, rad
(``RealTarget.limit_margin``'s default)."""
UNSAFE_FLAG = "--unsafe-allow-step-start"
"""The option that lets the real target start with a step (``--start policy``) or a shorter ramp."""
SMOOTHSTEP_MAX_SLOPE = 1.5
"""The steepest slope of ``3x^2 - 2x^3`` on [0, 1] (at x = 1/2), dimensionless."""


@dataclass(frozen=True)
class RampLimit:
    """The shortest safe HOLD ramp and the joint that sets it."""

    seconds: float
    """T_min, s."""
    joint: str
    """The joint with the largest ``1.5 E Kp dt / cap``."""
    error: float
    """That joint's largest start-up error E, rad."""
    kp: float
    """Its Kp, N*m/rad."""
    cap: float
    """Its torque cap, N*m."""
    dt: float
    """The control period, s."""

    @property
    def rounded_up(self) -> float:
        """``seconds`` rounded up to 0.01 s: the value to print and to suggest (never below the bound)."""
        return math.ceil(self.seconds * 100.0 - 1e-9) / 100.0

    @property
    def reason(self) -> str:
        """One line: the joint and the numbers of the bound."""
        return (
            f"{self.joint}: 1.5 x start-up error {self.error:.4g} rad x Kp {self.kp:.4g} N*m/rad x dt "
            f"{self.dt:.4g} s / torque cap {self.cap:.4g} N*m"
        )


def ramp_limit(
    kp: np.ndarray,
    cap: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    hold: np.ndarray,
    dt: float,
    joint_names: tuple[str, ...],
    limit_margin: float = START_LIMIT_MARGIN,
) -> RampLimit:
    """T_min (module docstring) for per-joint Kp (N*m/rad), caps (N*m), range and hold pose (rad), (n,)."""
    kp, cap, lo, up, h = (np.asarray(a, dtype=np.float64) for a in (kp, cap, lower, upper, hold))
    error = np.maximum(up + limit_margin - h, h - lo + limit_margin)
    per_joint = SMOOTHSTEP_MAX_SLOPE * error * kp * dt / cap
    j = int(np.argmax(per_joint))
    return RampLimit(
        seconds=float(per_joint[j]),
        joint=joint_names[j],
        error=float(error[j]),
        kp=float(kp[j]),
        cap=float(cap[j]),
        dt=float(dt),
    )


def min_ramp_time(
    policy: Any, hold: np.ndarray | None = None, limit_margin: float | None = None
) -> RampLimit:
    """``ramp_limit`` for a loaded ``OnnxPolicy`` (its Kp, robot, period; hold: default its ``hold_pose``)."""
    robot = policy.robot
    return ramp_limit(
        policy.kp,
        robot.torque_cap,
        robot.lower,
        robot.upper,
        policy.hold_pose if hold is None else hold,
        policy.policy_dt,
        tuple(robot.joint_names),
        START_LIMIT_MARGIN if limit_margin is None else limit_margin,
    )
