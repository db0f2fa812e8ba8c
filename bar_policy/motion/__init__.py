"""Motion clips for the tracking task (numpy and C MuJoCo only: the deploy side imports it).

``Clip`` and its NPZ/CSV loaders (``load_clip``, ``load_csv``, ``save_clip``; refusals raise ``ClipError``),
the named gestures (``gesture``, ``GESTURES``), the random trajectory generator (``random_clips``,
``RandomMotionConfig``), the clip sets with their ids (``clip_set``) and any library clip by name
(``library_clip``). See docs/tracking.md.
"""

from bar_policy.motion.clip import (
    MAX_JOINT_SPEED,
    Clip,
    ClipError,
    load_clip,
    load_csv,
    save_clip,
    validate_clip,
)
from bar_policy.motion.generator import RandomMotionConfig, motion_box, random_clips
from bar_policy.motion.gestures import GESTURES, gesture, gestures
from bar_policy.motion.library import CLIP_SETS, ClipSet, clip_set, library_clip

__all__ = [
    "CLIP_SETS",
    "GESTURES",
    "MAX_JOINT_SPEED",
    "Clip",
    "ClipError",
    "ClipSet",
    "RandomMotionConfig",
    "clip_set",
    "gesture",
    "gestures",
    "library_clip",
    "load_clip",
    "load_csv",
    "motion_box",
    "random_clips",
    "save_clip",
    "validate_clip",
]
