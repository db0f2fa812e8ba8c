"""The reach observation layout (``lite_reach_<mode>``), frozen by the golden files in ``obs/schemas/``."""

from __future__ import annotations

from bar_policy.obs.manager import ObservationSchema
from bar_policy.obs.robot_layout import robot_schema, state_terms, term
from bar_policy.robot.constants import load_robot

__all__ = ["schema"]


def schema(mode: str) -> ObservationSchema:
    """Version 1 of the bimanual reach layout: q, dq, the last action, both fingertips, both targets."""
    n = load_robot(mode).num_joints
    pos = ("fingertip_pos_left", "fingertip_pos_right", "target_pos_left", "target_pos_right")
    return robot_schema(f"lite_reach_{mode}", 1, mode, (*state_terms(n), *(term(p, 3) for p in pos)))
