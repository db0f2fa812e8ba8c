"""The piano observation layout (``lite_piano_<mode>``), frozen by its golden file in ``obs/schemas/``.

Humanoid Control's piano terms first, in its order (``target_keys, progress, key_pressed``), then the joint
state and the last action (lite-model.md).
"""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema
from bar_policy.obs.robot_layout import robot_schema, state_terms, term
from bar_policy.robot.constants import load_robot
from bar_policy.tasks.piano.terms import PIANO_KEYS, TARGET_FRAMES

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the piano layout: goal keys (11 frames x 49 keys), progress, keys down, q, dq, action."""
    n = load_robot(mode).num_joints
    keys = (
        term("target_keys", TARGET_FRAMES * PIANO_KEYS),
        term("progress", 1),
        term("key_pressed", PIANO_KEYS),
    )
    return robot_schema(f"lite_piano_{mode}", 1, mode, (*keys, *state_terms(n)))
