"""The identification excitation: slow ramps between held poses, and a low-amplitude multisine around each.

``Excitation.plan(robot, arms, seconds)`` lays out, per selected arm, ``POSES`` (left arm; the right arm is
mirrored): a 2.5 s smooth ramp (cosine) from where the arm is to each pose, then a multisine around it
(each joint its own set of frequencies, 0.11-1.07 Hz, so the joints move together but not in step; amplitude
``AMPLITUDE_RAD`` per joint). ``at(t)`` gives the position and velocity targets; the firmware's MIT law
(the robot's own Kp, Kd) tracks them, with the model's gravity torque at the target as feed-forward.

Several poses, not one: gravity loads each joint differently at each, which is what separates strength
from payload (``sysid_fit``). Every target stays ``LIMIT_MARGIN_RAD`` inside the joint limits (checked at
plan time, ``ValueError`` otherwise). The torque budget is the supervisor's (``robstride.identify``): 50 %
of each joint's cap, checked on every reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.robot.constants import RobotSpec

__all__ = ["AMPLITUDE_RAD", "LIMIT_MARGIN_RAD", "POSES", "Excitation", "min_seconds"]

POSES: tuple[tuple[float, ...], ...] = (
    (-0.5, -1.1, 0.0, -1.0, 0.0, 0.0, 0.0),
    (-1.2, -0.8, 0.4, -0.5, 0.5, 0.1, 0.2),
    (-0.15, -1.2, -0.4, -1.6, -0.5, -0.1, -0.2),
    (-0.9, -0.6, -0.3, -1.2, 0.3, -0.1, 0.2),
)
"""Held poses of the left arm, rad, shoulder pitch to wrist pitch (the right arm: roll, yaw, wrist yaw and
wrist roll negated)."""
MIRROR = np.array([1.0, -1.0, -1.0, 1.0, -1.0, -1.0, 1.0])
"""Sign from the left arm's pose to the right arm's, per joint."""
AMPLITUDE_RAD = np.array([0.2, 0.2, 0.25, 0.25, 0.15, 0.08, 0.1])
"""Multisine amplitude per joint (the sum of its sines peaks at this), rad."""
FREQS_HZ = np.array(
    [
        [0.13, 0.41, 0.83],
        [0.17, 0.49, 0.97],
        [0.23, 0.59, 1.07],
        [0.14, 0.47, 0.91],
        [0.19, 0.43, 0.79],
        [0.21, 0.37, 0.71],
        [0.11, 0.33, 0.67],
    ]
)
"""Multisine frequencies per joint, Hz (three each, none shared)."""
RAMP_S = 2.5
"""Ramp from one pose to the next, s."""
LIMIT_MARGIN_RAD = 0.1
"""Targets stay this far inside the joint limits, rad."""


def _smooth(x: np.ndarray | float) -> tuple[np.ndarray | float, np.ndarray | float]:
    """Cosine blend 0..1 and its derivative over x in [0, 1]."""
    return 0.5 - 0.5 * np.cos(np.pi * x), 0.5 * np.pi * np.sin(np.pi * x)


@dataclass(frozen=True)
class Excitation:
    """A planned excitation of some arm joints; ``at(t)`` is defined on ``[0, duration]``."""

    joints: np.ndarray
    """Canonical indices of the excited joints, shape (k,) (whole arms, shoulder to wrist)."""
    start: np.ndarray
    """Every joint's position at t = 0, rad, shape (num_joints,)."""
    poses: np.ndarray
    """Held poses of the excited joints, rad, shape (P, k)."""
    amplitude: np.ndarray
    """Multisine amplitude per excited joint, rad, shape (k,)."""
    freqs: np.ndarray
    """Frequencies per excited joint, Hz, shape (k, 3)."""
    hold_s: float
    """Multisine time at each pose, s."""

    @property
    def duration(self) -> float:
        """Total time, s: per pose a ramp and a hold, then a ramp back to ``start``."""
        return len(self.poses) * (RAMP_S + self.hold_s) + RAMP_S

    @classmethod
    def plan(cls, robot: RobotSpec, start: np.ndarray, arms: Sequence[str], seconds: float) -> Excitation:
        """Excite ``arms`` (``left``, ``right``) for ``seconds`` in all (ramps included) from ``start``."""
        joints: list[int] = []
        poses: list[np.ndarray] = []
        for arm in arms:
            group = f"{arm}_arm"
            idx = [j.index for j in robot.joints if j.group == group]
            if len(idx) != len(MIRROR):
                raise ValueError(f"{group}: expected {len(MIRROR)} joints, the robot has {len(idx)}")
            joints += idx
            sign = MIRROR if arm == "right" else np.ones(len(MIRROR))
            poses.append(np.array(POSES) * sign)
        p = np.concatenate(poses, axis=1)
        hold = (seconds - RAMP_S) / len(POSES) - RAMP_S
        if hold < 2.0:
            raise ValueError(f"excitation of {seconds:g} s is too short: needs >= {min_seconds():g} s")
        reps = len(joints) // len(MIRROR)
        ex = cls(
            joints=np.array(joints),
            start=np.asarray(start, dtype=np.float64).copy(),
            poses=p,
            amplitude=np.tile(AMPLITUDE_RAD, reps),
            freqs=np.tile(FREQS_HZ, (reps, 1)),
            hold_s=hold,
        )
        lo, hi = robot.lower[ex.joints] + LIMIT_MARGIN_RAD, robot.upper[ex.joints] - LIMIT_MARGIN_RAD
        for k, pose in enumerate(p):
            bad = (pose - ex.amplitude < lo) | (pose + ex.amplitude > hi)
            if bad.any():
                names = [robot.joint_names[j] for j in ex.joints[bad]]
                raise ValueError(f"pose {k}: {names} would come within {LIMIT_MARGIN_RAD} rad of a limit")
        return ex

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity targets of every joint at ``t`` s, rad and rad/s, shape (num_joints,)."""
        q, dq = self.start.copy(), np.zeros_like(self.start)
        seg = RAMP_S + self.hold_s
        k = int(t // seg) if t >= 0 else 0
        prev = self.start[self.joints] if k == 0 else self.poses[min(k, len(self.poses)) - 1]
        if k >= len(self.poses):  # the ramp back
            u = min(max((t - len(self.poses) * seg) / RAMP_S, 0.0), 1.0)
            s, ds = _smooth(u)
            q[self.joints] = prev + (self.start[self.joints] - prev) * s
            dq[self.joints] = (self.start[self.joints] - prev) * ds / RAMP_S
            return q, dq
        tau = t - k * seg
        pose = self.poses[k]
        if tau < RAMP_S:
            s, ds = _smooth(tau / RAMP_S)
            q[self.joints] = prev + (pose - prev) * s
            dq[self.joints] = (pose - prev) * ds / RAMP_S
            return q, dq
        h = tau - RAMP_S
        w = 2 * np.pi * self.freqs
        fade, dfade = _smooth(min(h, self.hold_s - h, 1.0))  # sines fade in and out over 1 s
        dfade = dfade * (1.0 if h < 1.0 else -1.0 if self.hold_s - h < 1.0 else 0.0)
        sines = np.sin(w * h).sum(axis=1) / 3
        dsines = (w * np.cos(w * h)).sum(axis=1) / 3
        a = self.amplitude
        q[self.joints] = pose + a * fade * sines
        dq[self.joints] = a * (fade * dsines + dfade * sines)
        return q, dq


def min_seconds() -> float:
    """The shortest excitation ``plan`` accepts, s (2 s of multisine at each pose)."""
    return len(POSES) * (RAMP_S + 2.0) + RAMP_S
