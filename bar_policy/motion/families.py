"""Held-out clip families the random generator never makes: the tracker's out-of-distribution check.

The training clips are cubic B-spline random walks (``generator``) and the held-out set adds seed-1 walks and
the keyframed gestures. These families differ in kind, each in two clips named ``<family>-<variant>``:

- ``periodic``: every joint swings ``amp_j (sin(2 pi f t + phi_j) - sin(phi_j)) / 2`` from ``piano_ready``
  (peak to peak ``amp_j``, 0.25-0.4 rad inside the box; 0.3 Hz, and 0.8 Hz at 60 % amplitude; random
  phases), faded in and out over 1.5 s with the minimum-jerk profile so the clip starts and ends at rest:
  a steady rhythm with no knots, unlike the walks.
- ``noisy``: seed-2 random walks with white Gaussian noise of ``NOISE_RAD`` (1.5 mrad) on every frame, the
  jitter of a retargeted recording. The noise is part of the reference, so about 0.89 of it (the share of
  a white spectrum above 5 Hz at 50 Hz) shows in ``q_cmd - q_ref`` of a policy that does not follow it:
  a chatter floor of about 1.3 mrad that is the reference's, not the policy's.
- ``hold``: long holds against gravity: both arms raised forward (4.6 N*m of gravity on each shoulder
  pitch) for 8 s, then out to the side (4.7 N*m on each shoulder roll) for 8 s, joined by 2 s minimum-jerk
  moves from and to ``piano_ready``.
- ``onearm``: one arm holds ``piano_ready`` while the other follows a seed-3 random walk (the walks move
  both arms together).

Every clip is checked like the generator's (inside ``MOTION_BOX``, no two bodies closer than 5 mm at any
frame, ``Clip.make``'s limit and speed checks); the noisy family's frames are clipped to the box after the
noise (at most the noise's size, at frames on the box's faces).
"""

from __future__ import annotations

import numpy as np

from bar_policy.motion.clip import Clip
from bar_policy.motion.curves import keyframe_frames, minimum_jerk
from bar_policy.motion.generator import MIRROR, RandomMotionConfig, motion_box, random_clip
from bar_policy.robot.constants import load_robot
from bar_policy.robot.kinematics import Kinematics

__all__ = ["FAMILIES", "HOLD_POSES_LEFT", "NOISE_RAD", "family_clips", "family_of"]

FAMILIES: tuple[str, ...] = ("periodic", "noisy", "hold", "onearm")
"""The families, in report order."""
NOISE_RAD = 0.0015
"""Standard deviation of the noisy family's per-frame noise, rad."""
HOLD_POSES_LEFT: dict[str, tuple[float, ...]] = {
    "forward": (-1.45, -1.45, 0.0, -0.3, -1.2, 0.0, 0.0),
    "side": (0.0, -0.05, 0.0, -0.3, -1.2, 0.0, 0.0),
}
"""Left-arm poses of the hold family, rad (canonical order); the right arm mirrors them. ``forward``: arm
raised forward, fingertip 0.6 m ahead at shoulder height; ``side``: arm out to the side, near horizontal."""
_CLEARANCE_M = 0.005
_FADE_S = 1.5
_FAMILY_SEEDS = {"noisy": 2, "onearm": 3}


def family_of(clip_name: str) -> str:
    """The report group of a clip: ``random`` (the walks), a family, or ``gestures`` (any other name)."""
    head = clip_name.split("-", 1)[0]
    if head == "random":
        return "random"
    return head if head in FAMILIES and "-" in clip_name else "gestures"


def _check(frames: np.ndarray, kin: Kinematics, lo: np.ndarray, hi: np.ndarray, name: str) -> None:
    if not (np.all(frames >= lo - 1e-9) and np.all(frames <= hi + 1e-9)):
        raise AssertionError(f"family clip {name} leaves the motion box")
    if not kin.collision_free(frames, _CLEARANCE_M):
        raise AssertionError(f"family clip {name} brings two bodies closer than {_CLEARANCE_M} m")


def _periodic(mode: str, rate_hz: float, kin: Kinematics, lo: np.ndarray, hi: np.ndarray) -> list[Clip]:
    center = load_robot(mode).pose("piano_ready")
    n = center.size
    room = 0.9 * np.minimum(center - lo, hi - center)  # the largest amplitude inside the box
    amp = np.minimum(np.r_[np.tile([0.3, 0.25, 0.3, 0.4, 0.25, 0.3, 0.3], 2), np.full(n - 14, 0.2)], room)
    rng = np.random.default_rng(4)
    length_s = 12.0
    t = np.arange(round(length_s * rate_hz) + 1) / rate_hz
    fade = minimum_jerk(t / _FADE_S) * minimum_jerk((length_s - t) / _FADE_S)
    clips = []
    for variant, freq, share in (("slow", 0.3, 1.0), ("fast", 0.8, 0.6)):
        phase = rng.uniform(0, 2 * np.pi, n)
        scale = share
        while True:  # shrink until no two bodies come within the clearance (deterministic)
            wave = np.sin(2 * np.pi * freq * t[:, None] + phase) - np.sin(phase)  # 0 at t = 0
            frames = center + fade[:, None] * scale * amp * wave / 2
            if kin.collision_free(frames, _CLEARANCE_M):
                break
            scale *= 0.8
        _check(frames, kin, lo, hi, f"periodic-{variant}")
        clips.append(Clip.make(f"periodic-{variant}", rate_hz, frames, mode))
    return clips


def _noisy(mode: str, rate_hz: float, kin: Kinematics, lo: np.ndarray, hi: np.ndarray) -> list[Clip]:
    rng = np.random.default_rng(_FAMILY_SEEDS["noisy"])
    clips = []
    for i in range(2):
        walk = random_clip(rng, 20.0, name="walk", mode=mode, rate_hz=rate_hz, kinematics=kin)
        frames = walk.joint_pos.astype(np.float64)
        noise = rng.normal(0.0, NOISE_RAD, frames.shape)
        noise[:3] = noise[-3:] = 0.0  # start and end on the walk's rest frames
        frames = np.clip(frames + noise, lo, hi)
        name = f"noisy-{i:03d}"
        _check(frames, kin, lo, hi, name)
        clips.append(Clip.make(name, rate_hz, frames, mode))
    return clips


def _hold(mode: str, rate_hz: float, kin: Kinematics, lo: np.ndarray, hi: np.ndarray) -> list[Clip]:
    robot = load_robot(mode)
    ready = robot.pose("piano_ready")

    def pose(name: str) -> np.ndarray:
        q = ready.copy()
        left = np.array(HOLD_POSES_LEFT[name])
        q[:14] = np.r_[left, MIRROR * left]
        return q

    clips = []
    for variant, order in (("forward-side", ("forward", "side")), ("side-forward", ("side", "forward"))):
        a, b = pose(order[0]), pose(order[1])
        keys = np.array([ready, ready, a, a, b, b, ready, ready])
        frames = keyframe_frames(keys, np.array([0.5, 2.0, 8.0, 2.0, 8.0, 2.0, 1.0]), rate_hz)
        name = f"hold-{variant}"
        _check(frames, kin, lo, hi, name)
        clips.append(Clip.make(name, rate_hz, frames, mode))
    return clips


def _onearm(mode: str, rate_hz: float, kin: Kinematics, lo: np.ndarray, hi: np.ndarray) -> list[Clip]:
    ready = load_robot(mode).pose("piano_ready")
    rng = np.random.default_rng(_FAMILY_SEEDS["onearm"])
    cfg = RandomMotionConfig()
    clips = []
    for still, cols in (("left", slice(0, 7)), ("right", slice(7, 14))):
        while True:  # the next walk whose moving arm keeps clear of the still one
            walk = random_clip(rng, 20.0, name="walk", mode=mode, rate_hz=rate_hz, config=cfg, kinematics=kin)
            frames = walk.joint_pos.astype(np.float64)
            # The still arm holds piano_ready; the moving arm starts there too (a 2 s minimum-jerk move to
            # the walk's first pose, held 0.5 s, keeps the clip's start on piano_ready at rest).
            lead = keyframe_frames(np.array([ready, ready, frames[0]]), np.array([0.5, 2.0]), rate_hz)
            frames = np.concatenate([lead, frames[1:]])
            frames[:, cols] = ready[cols]
            frames[:, 14:] = ready[14:]
            if kin.collision_free(frames, _CLEARANCE_M):
                break
        name = f"onearm-{still}-still"
        _check(frames, kin, lo, hi, name)
        clips.append(Clip.make(name, rate_hz, frames, mode))
    return clips


_BUILDERS = {"periodic": _periodic, "noisy": _noisy, "hold": _hold, "onearm": _onearm}


def family_clips(mode: str = "arms", rate_hz: float = 50.0) -> list[Clip]:
    """Every family's clips, in ``FAMILIES`` order (8 clips, 2 per family; a pure function of its args)."""
    kin = Kinematics(mode)
    lo, hi = motion_box(mode)
    return [clip for fam in FAMILIES for clip in _BUILDERS[fam](mode, rate_hz, kin, lo, hi)]
