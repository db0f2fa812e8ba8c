"""The reach ship gate (``TaskRecord.gate``; ``bar_policy.quality.gate`` applies it)."""

from __future__ import annotations

from bar_policy.quality.gate import GateThresholds

__all__ = ["GATE"]

GATE = GateThresholds(min_success_pct=95.0, max_median_end_cm=0.6)
"""reach: every held-out episode completes, <= 0.5 % of ticks at a torque cap, chatter <= 5 mrad on
    every episode (of q_cmd itself), >= 95 % of target segments reached, and the median segment-end
    distance over both hands <= 0.6 cm (the robustness targets' figure for every suite row: the shipped
    file's worst row is 0.41 cm, its nominal 0.29). The MJX evaluation during training has no median
    (its sums give the mean): there it counts as not measured, the same for every iterate, so the ranking
    of iterates is unchanged."""
