"""The track ship gate (``TaskRecord.gate``; ``bar_policy.quality.gate`` applies it)."""

from __future__ import annotations

from bar_policy.quality.gate import GateThresholds

__all__ = ["GATE"]

GATE = GateThresholds(max_joint_error_rad=0.02, max_fingertip_error_cm=1.0)
"""track: every held-out clip completes, <= 0.5 % of ticks at a torque cap, chatter <= 5 mrad on
    every clip (of q_cmd minus the reference), mean joint error <= 0.02 rad, mean fingertip error
    <= 1.0 cm."""
