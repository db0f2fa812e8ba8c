"""The observation terms track adds to the robot's (``obs.terms.ROBOT_TERMS``): the reference with lookahead.

Sized by the schema's ``lookahead_steps`` K and ``body_names`` (``obs.terms``'s lookahead size rules); the
reference source feeds them (``reference.py``, from ``shared.reference_inputs``).
"""

from __future__ import annotations

from bar_policy.obs.terms import TermKind

__all__ = ["TERMS"]

TERMS: dict[str, TermKind] = {
    "motion_joint_pos": TermKind(
        size="lookahead_joints",
        category="command",
        unit="rad",
        doc="reference joint positions at the next lookahead_steps frames, frame-major, canonical order",
    ),
    "motion_body_pos_b": TermKind(
        size="lookahead_body_pos",
        category="command",
        unit="m",
        doc="reference positions of body_names in the chest (torso) frame at the next lookahead_steps "
        "frames; frame-major, then body, then xyz (Humanoid Control's name)",
    ),
    "motion_body_ori_b": TermKind(
        size="lookahead_body_ori",
        category="command",
        unit="1",
        doc="reference orientations of body_names in the chest frame as 6-D (rotation matrix columns 0-1, "
        "row-major) at the next lookahead_steps frames; frame-major, then body (Humanoid Control's name)",
    ),
}
"""Term name -> meaning (``TaskRecord.terms``)."""
