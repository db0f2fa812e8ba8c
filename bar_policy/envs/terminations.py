"""Termination functions of the tasks: boolean scalars of arrays, rows of a task's termination table.

Plain jnp arithmetic on unbatched inputs (``envs.term_table.TerminationTerm``'s ``fn``). The robot env ends
every task's episodes on ``non_finite``; tracking ends them on ``farther_than`` of its bodies' distances.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["farther_than", "non_finite"]


def non_finite(finite: jax.Array) -> jax.Array:
    """True when the physics state is not finite (``finite``: boolean scalar, every qpos and qvel finite)."""
    return jnp.logical_not(finite)


def farther_than(distance: jax.Array, limit: float) -> jax.Array:
    """True when any of ``distance`` (shape (B,), m) exceeds ``limit`` (m); never when ``limit`` is 0."""
    return (jnp.max(distance) > limit) & (limit > 0)
