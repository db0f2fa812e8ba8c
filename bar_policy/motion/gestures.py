"""Named gestures of the Lite, made here from keyframes (numpy only, nothing downloaded).

Wave, clap, reach sweep, and the approach from hanging arms to piano-ready.

Each gesture is a list of keyframe poses joined by rest-to-rest minimum-jerk segments
(``curves.keyframe_frames``): the robot stops at every keyframe, and a segment of duration T moving a joint by
d peaks at 1.875 d / T rad/s and 5.77 d / T^2 rad/s^2. The keyframes were placed with inverse kinematics on
the fingertips (then rounded to 0.01 rad) and are checked by ``tests/motion``: inside ``MOTION_BOX`` (so
inside the joint limits), no self-collision closer than 5 mm along the whole gesture, and speeds within the
random generator's bound (``RandomMotionConfig().speed_bound``, 2.5 rad/s). Peak speeds and accelerations
of each gesture are listed in docs/tracking.md.

Poses (canonical order, left arm then right arm; fingertip positions in the chest frame, m):

- ``piano_ready`` / ``arms_hanging``: the robot's named poses (``RobotSpec.pose``).
- ``wave_up``: right hand raised beside the head, fingers up (right tip (0.13, -0.32, 0.62)); ``wave_out`` /
  ``wave_in``: the hand 8 cm further out / in (the forearm swings in the frontal plane).
- ``clap_open`` / ``clap_closed``: both hands in front of the chest, fingertips 44 cm / 7.6 cm apart (closer
  would bring the hands into contact, which a tracking reference should not ask for).
- ``sweep_centre`` / ``sweep_left`` / ``sweep_right``: both hands reaching forward (x ~ 0.45 m) at the
  centre, shifted 15 cm to the left, and to the right.
"""

from __future__ import annotations

import numpy as np

from bar_policy.motion.clip import Clip
from bar_policy.motion.curves import keyframe_frames
from bar_policy.robot.constants import load_robot

__all__ = ["GESTURES", "KEY_POSES", "gesture", "gestures"]

_PIANO_L = (0.3, -1.0, 0.0, -1.7, -1.2, 0.0, 0.3)
KEY_POSES: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    # name:          (left (pitch, roll, yaw, elbow, w_yaw, w_roll, w_pitch), right (same order))
    "wave_up": (_PIANO_L, (-0.31, 0.94, -0.71, -1.99, 1.03, 0.44, -0.51)),
    "wave_out": (_PIANO_L, (-0.32, 0.97, -0.81, -1.87, 0.98, 0.51, -0.45)),
    "wave_in": (_PIANO_L, (-0.24, 0.95, -0.62, -2.11, 1.11, 0.37, -0.61)),
    "clap_open": (
        (0.38, -1.02, 0.17, -1.75, -1.16, 0.07, 0.41),
        (0.38, 1.02, -0.17, -1.75, 1.16, 0.07, -0.41),
    ),
    "clap_closed": (
        (0.23, -1.04, -0.18, -1.85, -1.24, -0.12, 0.33),
        (0.23, 1.04, 0.18, -1.85, 1.24, -0.12, -0.33),
    ),
    "sweep_centre": (
        (-0.32, -1.07, -0.05, -1.28, -1.2, 0.08, 0.02),
        (-0.32, 1.07, 0.05, -1.28, 1.2, 0.08, -0.02),
    ),
    "sweep_left": (
        (-0.13, -0.83, 0.12, -1.24, -1.18, 0.14, 0.03),
        (-0.34, 1.46, 0.31, -1.36, 1.23, -0.02, -0.02),
    ),
    "sweep_right": (
        (-0.34, -1.46, -0.31, -1.36, -1.23, -0.02, 0.02),
        (-0.13, 0.83, -0.12, -1.24, 1.18, 0.14, -0.03),
    ),
}
"""Keyframe poses, rad: (left arm, right arm), canonical order; ``RobotSpec.pose`` names work too."""

GESTURES: dict[str, tuple[tuple[str, float], ...]] = {
    "wave": (
        ("piano_ready", 0.0),
        ("piano_ready", 0.5),
        ("wave_up", 1.5),
        ("wave_out", 0.4),
        ("wave_in", 0.5),
        ("wave_out", 0.5),
        ("wave_in", 0.5),
        ("wave_out", 0.5),
        ("wave_up", 0.4),
        ("piano_ready", 1.5),
        ("piano_ready", 0.5),
    ),
    "clap": (
        ("piano_ready", 0.0),
        ("piano_ready", 0.5),
        ("clap_open", 1.0),
        ("clap_closed", 0.5),
        ("clap_open", 0.5),
        ("clap_closed", 0.5),
        ("clap_open", 0.5),
        ("clap_closed", 0.5),
        ("clap_open", 0.5),
        ("piano_ready", 1.0),
        ("piano_ready", 0.5),
    ),
    "reach_sweep": (
        ("piano_ready", 0.0),
        ("piano_ready", 0.5),
        ("sweep_centre", 1.0),
        ("sweep_left", 1.2),
        ("sweep_right", 2.0),
        ("sweep_left", 2.0),
        ("sweep_centre", 1.2),
        ("piano_ready", 1.0),
        ("piano_ready", 0.5),
    ),
    "hanging_to_piano_ready": (
        ("arms_hanging", 0.0),
        ("arms_hanging", 0.5),
        ("piano_ready", 3.0),
        ("piano_ready", 1.0),
    ),
}
"""Gesture name -> ``((pose, seconds from the previous keyframe), ...)``: the first keyframe (time 0) is
where the clip starts, and a repeated pose is a hold."""


def _pose(name: str, mode: str) -> np.ndarray:
    robot = load_robot(mode)
    if name in KEY_POSES:
        q = np.zeros(robot.num_joints)
        q[:14] = (*KEY_POSES[name][0], *KEY_POSES[name][1])
        return q
    return robot.pose(name)


def gesture(name: str, mode: str = "arms", rate_hz: float = 50.0) -> Clip:
    """The named gesture as a validated clip (neck joints, if any, stay at 0).

    Raises:
        ValueError: an unknown name (the message lists ``GESTURES``).
    """
    if name not in GESTURES:
        raise ValueError(f"unknown gesture {name!r}; gestures: {sorted(GESTURES)}")
    steps = GESTURES[name]
    keys = np.array([_pose(p, mode) for p, _ in steps])
    durations = np.array([t for _, t in steps[1:]])
    return Clip.make(name, rate_hz, keyframe_frames(keys, durations, rate_hz), mode)


def gestures(mode: str = "arms", rate_hz: float = 50.0) -> list[Clip]:
    """Every gesture, in ``GESTURES`` order."""
    return [gesture(name, mode, rate_hz) for name in GESTURES]
