"""The identification excitation: slow ramps between held poses, and a low-amplitude multisine around each.

``Excitation.plan(robot, arms, seconds)`` lays out, per selected arm, ``POSES`` (left arm; the right arm is
mirrored): a 2.5 s smooth ramp (cosine) from where the arm is to each pose, then a multisine around it
(each joint its own set of frequencies, 0.11-1.07 Hz, so the joints move together but not in step; amplitude
``AMPLITUDE_RAD`` per joint). ``at(t)`` gives the position and velocity targets; the firmware's MIT law
(the robot's own Kp, Kd) tracks them, with the model's gravity torque at the target as feed-forward.

Then (``fast``, the default) the fast phase: a ramp to ``POSES[FAST_POSE]`` and each excited joint alone
for ``FAST_S`` on two sines at ``FAST_FREQS_HZ`` (``fast_segments`` gives where): the inertia torque
dominates there, so armature shows, and a wrist slides through MuJoCo's soft friction loss.

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

__all__ = ["AMPLITUDE_RAD", "FAST_AMPLITUDE_RAD", "LIMIT_MARGIN_RAD", "POSES", "Excitation", "min_seconds"]

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
FAST_POSE = 0
"""Index in ``POSES`` of the pose the fast single-joint phase holds."""
FAST_AMPLITUDE_RAD = np.array([0.06, 0.16, 0.12, 0.08, 0.12, 0.05, 0.05])
"""Fast phase: amplitude of each joint's two-sine sum, rad (peak speed ~0.8-1.1 rad/s on the shoulders and
elbow, 2.2 rad/s on the wrist yaw: about the ~2 rad/s an unloaded wrist needs to slide through MuJoCo's soft
friction loss of 0.6 N*m; 0.65 rad/s on the wrist roll and pitch). Set by the budget with 0.4 kg in the hand
(its inertia about a wrist is ~5x the wrist's own, its gravity ~0.9 N*m on the wrist roll and pitch, of a
2 N*m budget): measured, 0.1 rad on the shoulder pitch (3 Hz: its resonance at Kp 50) asked 8.52 N*m of its
8.5; 0.07 rad at 1.3 and 2.9 Hz on the wrist roll asked 2.00 of its 2.0 with 0.6 N*m of friction and
tripped the budget with 0.7, so the wrist roll and pitch take 0.05 (0.4 kg and 0.7 N*m: 48 % of a cap). The
shoulder roll and yaw move slower and further (``FAST_FREQS_HZ``)."""
FAST_FREQS_HZ = np.array([[1.3, 3.1], [0.6, 1.5], [0.8, 2.0], [1.3, 3.1], [1.9, 3.9]] + [[1.3, 2.9]] * 2)
"""Fast phase frequencies per joint, Hz: where the inertia torque (``I w^2 A``) dominates the gravity
stiffness and the friction, so armature (a few % of a shoulder's inertia) shows; two of them so a stiffness
(``~ q``) and an inertia (``~ w^2 q``) do not alias. The shoulder roll and yaw take lower ones (0.6 / 1.5
and 0.8 / 2.0 Hz, 0.16 and 0.12 rad): their fitted armature falls with frequency (left arm, friction +0.6
N*m, unloaded: roll -41 / -27 / -18 / -15 % at 2.3-5.3, 1.3-3.1, 0.8-2.0, 0.6-1.5 Hz; docs/sysid.md)."""
FAST_S = 2.0
"""Fast phase: seconds per joint (0.3 s fade in and out)."""
FAST_FADE_S = 0.3
"""Fade of the fast phase's sines in and out, s."""


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
    fast: bool = True
    """After the poses: a ramp to ``POSES[FAST_POSE]``, then each excited joint alone (the others held)
    ``FAST_S`` s at ``FAST_FREQS_HZ`` (``fast_segments``): what the per-joint armature and friction fit
    uses."""

    @property
    def fast_s(self) -> float:
        """Length of the fast phase, s (its ramp included; 0 without it)."""
        return RAMP_S + len(self.joints) * FAST_S if self.fast else 0.0

    @property
    def duration(self) -> float:
        """Total time, s: per pose a ramp and a hold, the fast phase, then a ramp back to ``start``."""
        return len(self.poses) * (RAMP_S + self.hold_s) + self.fast_s + RAMP_S

    def pose_segments(self) -> list[tuple[float, float]]:
        """``(t0, t1)`` of each pose's ramp in and multisine, s."""
        seg = RAMP_S + self.hold_s
        return [(k * seg, (k + 1) * seg) for k in range(len(self.poses))]

    def fast_segments(self) -> list[tuple[float, float, int]]:
        """``(t0, t1, joint)`` of each joint's fast segment, s and canonical index (empty without it)."""
        if not self.fast:
            return []
        t0 = len(self.poses) * (RAMP_S + self.hold_s) + RAMP_S
        return [(t0 + i * FAST_S, t0 + (i + 1) * FAST_S, int(j)) for i, j in enumerate(self.joints)]

    def _fast_pose(self) -> np.ndarray:
        return self.poses[FAST_POSE]

    @classmethod
    def plan(
        cls, robot: RobotSpec, start: np.ndarray, arms: Sequence[str], seconds: float, *, fast: bool = True
    ) -> Excitation:
        """Excite ``arms`` (``left``, ``right``) from ``start``.

        ``seconds`` of poses and multisines (ramps included), then (``fast``) the fast single-joint phase,
        ``fast_s`` more.
        """
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
            fast=fast,
        )
        lo, hi = robot.lower[ex.joints] + LIMIT_MARGIN_RAD, robot.upper[ex.joints] - LIMIT_MARGIN_RAD
        fast_amp = np.tile(FAST_AMPLITUDE_RAD, reps)
        checks = [(k, pose, ex.amplitude) for k, pose in enumerate(p)]
        if fast:
            checks.append((FAST_POSE, p[FAST_POSE], fast_amp))
        for k, pose, amp in checks:
            bad = (pose - amp < lo) | (pose + amp > hi)
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
        if k >= len(self.poses) and self.fast:
            u = t - len(self.poses) * seg
            if u < self.fast_s:
                return self._fast_at(u, prev)
            prev = self._fast_pose()
        if k >= len(self.poses):  # the ramp back
            u = min(max((t - len(self.poses) * seg - self.fast_s) / RAMP_S, 0.0), 1.0)
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

    def _fast_at(self, u: float, prev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Targets ``u`` s into the fast phase: the ramp from ``prev``, then one joint at a time."""
        q, dq = self.start.copy(), np.zeros_like(self.start)
        pose = self._fast_pose()
        if u < RAMP_S:
            s, ds = _smooth(u / RAMP_S)
            q[self.joints] = prev + (pose - prev) * s
            dq[self.joints] = (pose - prev) * ds / RAMP_S
            return q, dq
        q[self.joints] = pose
        h = u - RAMP_S
        i = min(int(h // FAST_S), len(self.joints) - 1)
        h -= i * FAST_S
        c = i % len(MIRROR)
        w = 2 * np.pi * FAST_FREQS_HZ[c]
        x = min(h, FAST_S - h, FAST_FADE_S) / FAST_FADE_S
        fade, dfade = _smooth(min(max(x, 0.0), 1.0))
        dfade = dfade / FAST_FADE_S * (1.0 if h < FAST_FADE_S else -1.0 if FAST_S - h < FAST_FADE_S else 0.0)
        a = FAST_AMPLITUDE_RAD[c]
        sines, dsines = np.sin(w * h).sum() / 2, (w * np.cos(w * h)).sum() / 2
        q[self.joints[i]] = pose[i] + a * fade * sines
        dq[self.joints[i]] = a * (fade * dsines + dfade * sines)
        return q, dq


def min_seconds() -> float:
    """The shortest excitation ``plan`` accepts, s (2 s of multisine at each pose)."""
    return len(POSES) * (RAMP_S + 2.0) + RAMP_S
