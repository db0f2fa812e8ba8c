"""Key-press counts of a step (placeholder until the reviewed module lands)."""

from __future__ import annotations

from bar_policy._array import Array, array_namespace

__all__ = ["step_counts"]


def step_counts(down: Array, goal: Array) -> tuple[Array, Array, Array]:
    """(true positives, false positives, false negatives) of bool (n_keys,) key states, as float32."""
    xp = array_namespace(down)
    d, g = down.astype(xp.float32), goal.astype(xp.float32)
    return xp.sum(d * g), xp.sum(d * (1.0 - g)), xp.sum((1.0 - d) * g)
