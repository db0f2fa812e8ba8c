"""The reach ship gate (``TaskRecord.gate``; ``bar_policy.quality.gate`` applies it)."""

from __future__ import annotations

from bar_policy.quality.gate import GateThresholds

__all__ = ["GATE"]

GATE = GateThresholds(min_success_pct=95.0)
"""reach: every held-out episode completes, <= 0.5 % of ticks at a torque cap, chatter <= 5 mrad on
    every episode (of q_cmd itself), >= 95 % of target segments reached."""
