"""The observation terms reach adds to the robot's (``obs.terms.ROBOT_TERMS``): the two fingertip targets.

Its command source feeds them (``commands.py``); the fingertips themselves are robot terms, computed by the
runtime.
"""

from __future__ import annotations

from bar_policy.obs.terms import TermKind

__all__ = ["TERMS"]

TERMS: dict[str, TermKind] = {
    "target_pos_left": TermKind(
        size=3, category="command", unit="m", doc="left fingertip target in the chest frame"
    ),
    "target_pos_right": TermKind(
        size=3, category="command", unit="m", doc="right fingertip target in the chest frame"
    ),
}
"""Term name -> meaning (``TaskRecord.terms``)."""
