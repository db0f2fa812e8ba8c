"""The identification excitation: slow ramps between held poses, and a low-amplitude multisine around each.

``Excitation.plan(robot, arms, seconds)`` lays out, per selected arm, ``POSES`` (left arm; the right arm is
mirrored): a 2.5 s smooth ramp (cosine) from where the arm is to each pose, then a multisine around it
(each joint its own set of frequencies, 0.11-1.07 Hz, so the joints move together but not in step; amplitude
``AMPLITUDE_RAD`` per joint). ``at(t)`` gives the position and velocity targets; the firmware's MIT law
(the robot's own Kp, Kd) tracks them, with the model's gravity torque at the target as feed-forward.

Then (``fast``, the default) the fast phase: a ramp to ``POSES[FAST_POSE]`` and each excited joint alone
for ``FAST_S`` on two sines at ``FAST_FREQS_HZ`` (``fast_segments`` gives where): the inertia torque
dominates there, so armature shows, and a wrist slides through MuJoCo's soft friction loss.

With a known payload in the hand (``plan``'s ``payload_moment_kgm``; a heavy one takes the wrist roll and
pitch's fast amplitude down, ``HEAVY_PAYLOAD_KGM``), after the fast phase the lever phase: a ramp to
``lever_pose`` (the fast pose with the wrist bent, ``LEVER_WRIST``), then each arm's wrist yaw alone for
``LEVER_S`` on a wide, slow two-sine sweep (``lever_segments``): the payload swings about the yaw's axis,
from which it is ~2 cm in every other pose, so its known gravity torque (~+-0.5 N*m at 0.4 kg) varies with
the yaw and tells the yaw's strength from its friction.

Several poses, not one: gravity loads each joint differently at each, which is what separates strength
from payload (``sysid_fit``). Every target stays ``LIMIT_MARGIN_RAD`` inside the joint limits (checked at
plan time, ``ValueError`` otherwise). The torque budget is the supervisor's
(``robstride.excitation_run``): 50 % of each joint's cap, checked on every reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bar_policy.robot.constants import RobotSpec

__all__ = [
    "AMPLITUDE_RAD",
    "FAST_AMPLITUDE_RAD",
    "HEAVY_PAYLOAD_KGM",
    "LEVER_WRIST",
    "LIMIT_MARGIN_RAD",
    "POSES",
    "Excitation",
    "min_seconds",
]

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
LEVER_WRIST = (-0.3, -0.45, 0.55)
"""Lever phase: wrist yaw, roll and pitch of the left arm, rad (the right arm's mirrored), at
``POSES[FAST_POSE]``'s shoulders and elbow. Bent so, the fingertip (0.225 m along the hand) leaves the wrist
yaw's axis: a payload there has ~0.14 m of lever about the yaw (~2 cm with the roll and pitch at 0), its
gravity torque on the yaw +0.43 .. -0.54 N*m at 0.4 kg over the sweep (0.01-0.23 N*m in ``POSES``); the yaw
centred where the whole hand's gravity torque on it changes sign. Each bend is the joint's limit less
``LIMIT_MARGIN_RAD`` and ~0.14 rad of room. Chosen from a grid of arm poses and wrist bends by the range
of the payload's torque on the yaw over its sweep: every arm pose gave ~1 N*m with the wrist bent so, and
~0.3 N*m unbent."""
LEVER_JOINT = 4
"""Lever phase: the joint swept, index in an arm (the wrist yaw)."""
LEVER_AMPLITUDE_RAD = 0.9
"""Lever phase: amplitude of the yaw's two-sine sum, rad (the targets' peak speed 2.4 rad/s, measured up to
3.6 with 0.4 kg at the fingertip: above the speed a loaded yaw needs to slide through MuJoCo's soft friction
loss, where its friction is ``+-f``)."""
LEVER_FREQS_HZ = (0.25, 0.6)
"""Lever phase: the sweep's two frequencies, Hz: slow, so the gravity torque dominates the inertia's (at
0.35 and 0.8 Hz, the yaw centred at 0: the payload's inertia asked 0.4 N*m, the yaw 46 % of its cap; at
these, 36 %); two, so a gravity stiffness (``~ q``) and an inertia (``~ w^2 q``) do not alias."""
LEVER_S = 5.0
"""Lever phase: seconds per swept joint (``FAST_FADE_S`` fade in and out)."""
HEAVY_PAYLOAD_KGM = 0.05
"""A known payload whose moment about its hand's origin (mass x the centre's distance) exceeds this, kg*m,
has the wrist roll and pitch's fast amplitude at ``HEAVY_PAYLOAD_WRIST_RAD`` (``plan``'s
``payload_moment_kgm``). Measured, strength 0.9: 0.4 kg at the fingertip (0.090 kg*m) at 0.05 rad asked the
wrist roll 2.00 N*m of its 2.0 budget with friction 0.6 N*m and tripped (its static load dominates: the
payload's gravity ~0.96 N*m plus the friction, both / 0.9), at 0.04 rad 49 % of its cap, at 0.03 rad 47 %;
0.4 kg at the palm (0.040 kg*m) at 0.05 rad: 45 % with friction 0.7, and at 0.04 rad its roll and pitch
too slow to slide through that friction (pitch strength -7 %, armatures +90 and +127 %)."""
HEAVY_PAYLOAD_WRIST_RAD = 0.04
"""The wrist roll and pitch's fast amplitude with a heavy known payload (``HEAVY_PAYLOAD_KGM``), rad."""
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
    fast_amplitude: np.ndarray | None = None
    """Fast phase: amplitude of each excited joint's two-sine sum, rad, shape (k,); None:
    ``FAST_AMPLITUDE_RAD`` on each arm."""
    lever_pose: np.ndarray | None = None
    """The lever phase's held pose of the excited joints, rad, shape (k,): ``POSES[FAST_POSE]`` with each
    arm's wrist at ``LEVER_WRIST`` (mirrored on the right arm); None: no lever phase. After
    the fast phase, a ramp to it, then each arm's wrist yaw alone ``LEVER_S`` s on a wide sweep
    (``lever_segments``): for a known payload, whose gravity torque on the yaw it makes large."""

    @property
    def fast_s(self) -> float:
        """Length of the fast phase, s (its ramp included; 0 without it)."""
        return RAMP_S + len(self.joints) * FAST_S if self.fast else 0.0

    @property
    def lever_s(self) -> float:
        """Length of the lever phase, s (its ramp included; 0 without it)."""
        return 0.0 if self.lever_pose is None else RAMP_S + len(self._lever_joints()) * LEVER_S

    @property
    def duration(self) -> float:
        """Total time, s: the poses (a ramp and a hold each), the fast and lever phases, the ramp back."""
        return self._poses_s + self.fast_s + self.lever_s + RAMP_S

    @property
    def _poses_s(self) -> float:
        return len(self.poses) * (RAMP_S + self.hold_s)

    def pose_segments(self) -> list[tuple[float, float]]:
        """``(t0, t1)`` of each pose's ramp in and multisine, s."""
        seg = RAMP_S + self.hold_s
        return [(k * seg, (k + 1) * seg) for k in range(len(self.poses))]

    def fast_segments(self) -> list[tuple[float, float, int]]:
        """``(t0, t1, joint)`` of each joint's fast segment, s and canonical index (empty without it)."""
        if not self.fast:
            return []
        t0 = self._poses_s + RAMP_S
        return [(t0 + i * FAST_S, t0 + (i + 1) * FAST_S, int(j)) for i, j in enumerate(self.joints)]

    def lever_segments(self) -> list[tuple[float, float, int]]:
        """``(t0, t1, joint)`` of each wrist yaw's sweep in ``lever_pose``, s and canonical index.

        Empty without the lever phase.
        """
        if self.lever_pose is None:
            return []
        t0 = self._poses_s + self.fast_s + RAMP_S
        return [(t0 + i * LEVER_S, t0 + (i + 1) * LEVER_S, j) for i, j in enumerate(self._lever_joints())]

    def _lever_joints(self) -> list[int]:
        return [int(j) for j in self.joints[LEVER_JOINT :: len(MIRROR)]]

    def _fast_pose(self) -> np.ndarray:
        return self.poses[FAST_POSE]

    @classmethod
    def plan(
        cls,
        robot: RobotSpec,
        start: np.ndarray,
        arms: Sequence[str],
        seconds: float,
        *,
        fast: bool = True,
        payload_moment_kgm: float | None = None,
    ) -> Excitation:
        """Excite ``arms`` (``left``, ``right``) from ``start``.

        ``seconds`` of poses and multisines (ramps included), then (``fast``) the fast single-joint phase,
        ``fast_s`` more. ``payload_moment_kgm``: a known payload in each hand, its mass times its centre's
        distance from the hand's origin, kg*m (None: none known): the lever phase, ``lever_s`` more, and
        above ``HEAVY_PAYLOAD_KGM`` the wrist roll and pitch's fast amplitude ``HEAVY_PAYLOAD_WRIST_RAD``.
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
        lever_pose = None
        arm_amp = FAST_AMPLITUDE_RAD.copy()
        if payload_moment_kgm is not None and payload_moment_kgm > HEAVY_PAYLOAD_KGM:
            arm_amp[5:7] = HEAVY_PAYLOAD_WRIST_RAD
        fast_amp = np.tile(arm_amp, reps)
        if payload_moment_kgm is not None:
            lever_pose = p[FAST_POSE].reshape(reps, len(MIRROR)).copy()
            lever_pose[:, 4:7] = np.array(LEVER_WRIST) * np.array(
                [MIRROR[4:7] if arm == "right" else np.ones(3) for arm in arms]
            )
            lever_pose = lever_pose.ravel()
        ex = cls(
            joints=np.array(joints),
            start=np.asarray(start, dtype=np.float64).copy(),
            poses=p,
            amplitude=np.tile(AMPLITUDE_RAD, reps),
            freqs=np.tile(FREQS_HZ, (reps, 1)),
            hold_s=hold,
            fast=fast,
            fast_amplitude=fast_amp,
            lever_pose=lever_pose,
        )
        lo, hi = robot.lower[ex.joints] + LIMIT_MARGIN_RAD, robot.upper[ex.joints] - LIMIT_MARGIN_RAD
        checks = [(str(k), pose, ex.amplitude) for k, pose in enumerate(p)]
        if fast:
            checks.append((str(FAST_POSE), p[FAST_POSE], fast_amp))
        if lever_pose is not None:
            lever_amp = np.tile(np.eye(len(MIRROR))[LEVER_JOINT] * LEVER_AMPLITUDE_RAD, reps)
            checks.append(("lever", lever_pose, lever_amp))
        for k, pose, amp in checks:
            bad = (pose - amp < lo) | (pose + amp > hi)
            if bad.any():
                names = [robot.joint_names[j] for j in ex.joints[bad]]
                raise ValueError(f"pose {k}: {names} would come within {LIMIT_MARGIN_RAD} rad of a limit")
        return ex

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity targets of every joint at ``t`` s, rad and rad/s, shape (num_joints,)."""
        seg = RAMP_S + self.hold_s
        k = int(t // seg) if t >= 0 else 0
        prev = self.start[self.joints] if k == 0 else self.poses[min(k, len(self.poses)) - 1]
        if k >= len(self.poses):
            u = t - self._poses_s
            if self.fast:
                if u < self.fast_s:
                    return self._fast_at(u, prev)
                u, prev = u - self.fast_s, self._fast_pose()
            if self.lever_pose is not None:
                if u < self.lever_s:
                    return self._lever_at(u, prev, self.lever_pose)
                u, prev = u - self.lever_s, self.lever_pose
            return self._ramp(min(max(u, 0.0), RAMP_S), prev, self.start[self.joints])  # the ramp back
        tau = t - k * seg
        pose = self.poses[k]
        if tau < RAMP_S:
            return self._ramp(tau, prev, pose)
        q, dq = self.start.copy(), np.zeros_like(self.start)
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
        pose = self._fast_pose()
        if u < RAMP_S:
            return self._ramp(u, prev, pose)
        h = u - RAMP_S
        i = min(int(h // FAST_S), len(self.joints) - 1)
        c = i % len(MIRROR)
        a = FAST_AMPLITUDE_RAD[c] if self.fast_amplitude is None else self.fast_amplitude[i]
        return self._sweep(pose, i, h - i * FAST_S, FAST_S, FAST_FREQS_HZ[c], float(a))

    def _lever_at(self, u: float, prev: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Targets ``u`` s into the lever phase: the ramp from ``prev`` to ``pose``, then each wrist yaw."""
        if u < RAMP_S:
            return self._ramp(u, prev, pose)
        order = self._lever_joints()
        h = u - RAMP_S
        n = min(int(h // LEVER_S), len(order) - 1)
        i = int(np.flatnonzero(self.joints == order[n])[0])
        freqs = np.array(LEVER_FREQS_HZ)
        return self._sweep(pose, i, h - n * LEVER_S, LEVER_S, freqs, LEVER_AMPLITUDE_RAD)

    def _ramp(self, u: float, prev: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cosine ramp from ``prev`` to ``pose`` of the excited joints, ``u`` s into its ``RAMP_S``."""
        q, dq = self.start.copy(), np.zeros_like(self.start)
        s, ds = _smooth(u / RAMP_S)
        q[self.joints] = prev + (pose - prev) * s
        dq[self.joints] = (pose - prev) * ds / RAMP_S
        return q, dq

    def _sweep(
        self, pose: np.ndarray, i: int, h: float, seg_s: float, freqs: np.ndarray, a: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``pose`` held, excited joint ``i`` alone, ``h`` s into its ``seg_s`` s segment.

        Two sines at ``freqs``, their sum peaking at ``a``, faded in and out over ``FAST_FADE_S``.
        """
        q, dq = self.start.copy(), np.zeros_like(self.start)
        q[self.joints] = pose
        w = 2 * np.pi * freqs
        x = min(h, seg_s - h, FAST_FADE_S) / FAST_FADE_S
        fade, dfade = _smooth(min(max(x, 0.0), 1.0))
        dfade = dfade / FAST_FADE_S * (1.0 if h < FAST_FADE_S else -1.0 if seg_s - h < FAST_FADE_S else 0.0)
        sines, dsines = np.sin(w * h).sum() / 2, (w * np.cos(w * h)).sum() / 2
        q[self.joints[i]] = pose[i] + a * fade * sines
        dq[self.joints[i]] = a * (fade * dsines + dfade * sines)
        return q, dq


def min_seconds() -> float:
    """The shortest excitation ``plan`` accepts, s (2 s of multisine at each pose)."""
    return len(POSES) * (RAMP_S + 2.0) + RAMP_S
