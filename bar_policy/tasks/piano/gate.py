"""The piano ship gate (``TaskRecord.gate``; ``bar_policy.quality.gate`` applies it)."""

from __future__ import annotations

from bar_policy.quality.gate import GateThresholds

__all__ = ["GATE"]

GATE = GateThresholds(min_success_pct=90.0)
"""piano: the safety and smoothness gate of reach and track, and key-press F1 >= 0.9 on the held-out songs
    (``success_pct`` = 100 x the episode-level F1)."""
