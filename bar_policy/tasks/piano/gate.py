"""The piano ship gate (``TaskRecord.gate``; ``bar_policy.quality.gate`` applies it)."""

from __future__ import annotations

from bar_policy.quality.gate import GateThresholds

__all__ = ["GATE", "RECALL_GROUPS"]

RECALL_GROUPS: tuple[str, ...] = (
    "held-out black keys",
    "held-out white keys",
    "random black keys",
    "random white keys",
)
"""The recall rows of the gate (``results.PianoEval.gate_report``'s ``recall_pct``): the pooled recall of
the goal key-ticks of each key colour on the held-out songs (``heldout.EVAL_HELDOUT``) and on the random
songs of the bank's kind (``heldout.random_eval_songs``: a seed never trained on)."""

GATE = GateThresholds(min_success_pct=90.0, min_recall_pct=85.0, recall_groups=RECALL_GROUPS)
"""piano: the safety and smoothness gate of reach and track on the held-out songs, key-press F1 >= 0.9 on
    them (``success_pct`` = 100 x the F1, step mean over the songs' windows), and the recall of black and of
    white goal key-ticks >= 85 % each, on the held-out songs and on the random songs: a file that skips the
    black keys (1.5 % of the library's held-out key-ticks) no longer passes on the white ones alone."""
