"""Recall per key colour in the deploy-side evaluation (the MJX evaluation's ``recall_black``, ``_white``).

A song's or a run's four counts (``COLOUR_COUNTS``: goal key-ticks of each colour pressed and missed, from
``metrics.colour_counts``) give each colour's pooled recall ``tp / (tp + fn)``: 1 where the colour has no
goal key-tick (``metrics.scores``' ``zero_division=1`` rule), written ``-`` in the printed line. Plain
Python: the deploy side imports it without jax.
"""

from __future__ import annotations

from collections.abc import Mapping

from bar_policy.tasks.piano.metrics import Counts, scores

__all__ = ["COLOUR_COUNTS", "counts_of", "recalls", "text"]

COLOUR_COUNTS = ("true_pos_black", "false_neg_black", "true_pos_white", "false_neg_white")
"""The per-colour counts (``SongResult``'s fields, the env's metrics of the same names)."""


def counts_of(obj: object) -> dict[str, int]:
    """``obj``'s ``COLOUR_COUNTS`` attributes (a ``SongResult``)."""
    return {k: int(getattr(obj, k)) for k in COLOUR_COUNTS}


def recalls(c: Mapping[str, int]) -> dict[str, float]:
    """``{"recall_black": r, "recall_white": r}`` of the counts ``c``, pooled (1 for a colour with none)."""
    return {
        f"recall_{colour}": float(scores(Counts(c[f"true_pos_{colour}"], 0, c[f"false_neg_{colour}"])).recall)
        for colour in ("black", "white")
    }


def text(c: Mapping[str, int]) -> str:
    """``recall of goal key-ticks (pooled): black 0.512 of 41, white 0.915 of 3145`` (``- of 0``: none)."""

    def one(tp: int, fn: int) -> str:
        return f"{tp / (tp + fn):.3f} of {tp + fn}" if tp + fn else "- of 0"

    black = one(c["true_pos_black"], c["false_neg_black"])
    white = one(c["true_pos_white"], c["false_neg_white"])
    return f"recall of goal key-ticks (pooled): black {black}, white {white}"
