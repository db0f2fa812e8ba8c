"""Seeded smooth random joint trajectories inside a motion box, free of self-collision (numpy, C MuJoCo).

Each clip is a uniform cubic B-spline (``bar_policy.motion.curves``) whose control points take a random
walk in ``MOTION_BOX``: every knot, each joint steps by ``U(-s * max_step, s * max_step)`` (reflected at the
box walls, which never lengthens a step), with one speed factor ``s ~ U(speed_scale)`` per clip. The first
three and the last three control points are equal, so a clip starts and ends at rest. A control point is
redrawn (up to ``max_tries`` times) while the span it completes brings two bodies closer than
``clearance`` at any frame (``Kinematics.collisions``); if that fails the clip restarts from a new pose.

Bounds that hold for every frame of every clip, by construction (see ``curves``):

- position: inside ``MOTION_BOX`` (within the joint limits);
- speed: ``|dq| <= max_step / knot_s`` (default 1.0 / 0.4 = 2.5 rad/s);
- acceleration: ``|ddq| <= 2 * max_step / knot_s^2`` (default 12.5 rad/s^2);
- no self-collision at the frames (all body pairs the MJCF checks at least ``clearance`` = 5 mm apart).

The speed bound is below ``clip.MAX_JOINT_SPEED`` (5 rad/s), so every generated clip loads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bar_policy._array_cache import cached_arrays
from bar_policy.motion.clip import Clip
from bar_policy.motion.curves import bspline_frames
from bar_policy.robot.constants import MODES, load_robot
from bar_policy.robot.kinematics import Kinematics

__all__ = ["MIRROR", "MOTION_BOX_LEFT", "RandomMotionConfig", "motion_box", "random_clip", "random_clips"]

MOTION_BOX_LEFT: tuple[tuple[float, float], ...] = (
    (-1.6, 0.6),  # left_shoulder_pitch: from arm raised forward to slightly back
    (-math.pi / 2, 0.2),  # left_shoulder_roll: from hanging (the limit) to just above horizontal
    (-1.2, 1.2),  # left_shoulder_yaw
    (-2.2, 0.0),  # left_elbow_pitch: flexed to straight (the limit)
    (-1.5, 1.5),  # left_wrist_yaw
    (-0.6, 0.6),  # left_wrist_roll
    (-0.7, 0.7),  # left_wrist_pitch
)
"""Per-joint range of the random trajectories for the left arm, rad (pitch, roll, yaw, elbow, wrist yaw,
roll, pitch). It keeps the hands below the head and in front of or beside the chest (uniform samples in it
self-collide 5 % of the time against 27 % over the full joint ranges) and holds the named poses
``arms_hanging`` and ``piano_ready``. The right arm is the mirror image, ``MIRROR``."""

MIRROR = np.array([1.0, -1.0, -1.0, 1.0, -1.0, 1.0, -1.0])
"""Right-arm angles that mirror a left-arm pose: ``MIRROR * q_left`` (lite-model.md 1.2)."""

NECK_BOX = (-0.4, 0.4)
"""Range of each neck joint in ``arms_neck`` mode, rad."""


def motion_box(mode: str = "arms") -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of the random trajectories, rad, shape (n,) each, canonical order."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid modes: {list(MODES)}")
    left = np.array(MOTION_BOX_LEFT)
    right = np.sort(left * MIRROR[:, None], axis=1)
    lo = np.r_[left[:, 0], right[:, 0]]
    hi = np.r_[left[:, 1], right[:, 1]]
    n_neck = load_robot(mode).num_joints - 14
    return np.r_[lo, [NECK_BOX[0]] * n_neck], np.r_[hi, [NECK_BOX[1]] * n_neck]


@dataclass(frozen=True, kw_only=True)
class RandomMotionConfig:
    """Parameters of the random trajectory generator (bounds in the module docstring)."""

    knot_s: float = 0.4
    """B-spline knot spacing, s."""
    max_step: float = 1.0
    """Largest step of a control point per knot and joint at speed factor 1, rad."""
    speed_scale: tuple[float, float] = (0.3, 1.0)
    """Range of the per-clip speed factor s (steps are U(-s * max_step, s * max_step))."""
    clearance: float = 0.005
    """Smallest distance between two bodies the MJCF checks for collision, m."""
    max_tries: int = 30
    """Draws of one control point before the clip restarts."""

    def __post_init__(self) -> None:
        lo, hi = self.speed_scale
        if not (self.knot_s > 0 and self.max_step > 0 and 0 < lo <= hi <= 1):
            raise ValueError(
                f"need knot_s > 0 s, max_step > 0 rad and 0 < speed_scale low <= high <= 1, got {self}"
            )
        if not (self.clearance >= 0 and self.max_tries >= 1):
            raise ValueError(f"clearance must be >= 0 m and max_tries >= 1, got {self}")

    @property
    def speed_bound(self) -> float:
        """Largest joint speed of any clip, rad/s."""
        return self.max_step / self.knot_s

    @property
    def acceleration_bound(self) -> float:
        """Largest joint acceleration of any clip, rad/s^2."""
        return 2.0 * self.max_step / self.knot_s**2


def _reflect(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    x = np.where(x > hi, 2 * hi - x, x)
    return np.where(x < lo, 2 * lo - x, x)


def random_clip(
    rng: np.random.Generator,
    length_s: float,
    *,
    name: str,
    mode: str = "arms",
    rate_hz: float = 50.0,
    config: RandomMotionConfig | None = None,
    kinematics: Kinematics | None = None,
) -> Clip:
    """One random clip of at least ``length_s`` seconds (rounded up to whole knots), validated.

    Args:
        rng: the random source (``np.random.default_rng(seed)``); the clip is a pure function of its state.
        length_s: duration, s.
        name: clip name.
        mode: joint set.
        rate_hz: frame rate, Hz.
        config: generator parameters.
        kinematics: a ``Kinematics(mode)`` to reuse (built when None).
    """
    cfg = config or RandomMotionConfig()
    kin = kinematics or Kinematics(mode)
    lo, hi = motion_box(mode)
    spans = max(1, math.ceil(length_s / cfg.knot_s - 1e-9))
    while True:
        step = rng.uniform(*cfg.speed_scale) * cfg.max_step
        start = rng.uniform(lo, hi)
        if not kin.collision_free(start, cfg.clearance):
            continue
        ctrl = [start, start, start]
        ok = True
        # Spans 0 .. spans-3 get a free control point; the last two repeat it so the clip ends at rest.
        for k in range(spans):
            free = k < spans - 2
            for _ in range(cfg.max_tries if free else 1):
                c = _reflect(ctrl[-1] + rng.uniform(-step, step, lo.shape), lo, hi) if free else ctrl[-1]
                frames = bspline_frames(np.array([*ctrl[-3:], c]), cfg.knot_s, rate_hz)
                if kin.collision_free(frames, cfg.clearance):
                    break
            else:
                ok = False
                break
            ctrl.append(c)
        if ok:
            q = bspline_frames(np.array(ctrl), cfg.knot_s, rate_hz)
            return Clip.make(name, rate_hz, q, mode)


def random_clips(
    seed: int,
    count: int,
    length_s: float,
    *,
    prefix: str = "random",
    mode: str = "arms",
    rate_hz: float = 50.0,
    config: RandomMotionConfig | None = None,
    cache: bool = False,
) -> list[Clip]:
    """``count`` random clips from one seed, named ``<prefix>-s<seed>-<index>``.

    ``cache``: keep the frames on disk (``bar_policy._array_cache``, keyed on every argument, the package's
    files and the numpy and mujoco versions): the 64 clips of the ``train`` set take 0.9 s to generate on
    the project's 2-core CPU, while a cached entry loads (and the clips revalidate) in a few ms. The clips
    are the same either way, bit for bit (the frames are stored as the float32 they are).
    """
    cfg = config or RandomMotionConfig()

    def generate() -> list[Clip]:
        rng = np.random.default_rng(seed)
        kin = Kinematics(mode)
        return [
            random_clip(
                rng,
                length_s,
                name=f"{prefix}-s{seed}-{i:03d}",
                mode=mode,
                rate_hz=rate_hz,
                config=cfg,
                kinematics=kin,
            )
            for i in range(count)
        ]

    if not cache or count < 1:
        return generate()

    def frames() -> dict[str, np.ndarray]:
        clips = generate()
        q = np.concatenate([c.joint_pos for c in clips])
        return {"joint_pos": q, "num_frames": np.array([c.num_frames for c in clips], np.int64)}

    parts = {
        "seed": int(seed),
        "count": int(count),
        "length_s": float(length_s),
        "prefix": prefix,
        "mode": mode,
        "rate_hz": float(rate_hz),
        "config": repr(cfg),
    }
    arrays = cached_arrays("motion_random_clips", parts, ("joint_pos", "num_frames"), frames)
    chunks = np.split(arrays["joint_pos"], np.cumsum(arrays["num_frames"])[:-1])
    return [Clip.make(f"{prefix}-s{seed}-{i:03d}", rate_hz, q, mode) for i, q in enumerate(chunks)]
