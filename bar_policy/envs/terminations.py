"""Termination functions of the tasks: boolean scalars of arrays, rows of a task's termination table.

Plain jnp arithmetic on unbatched inputs (``envs.term_table.TerminationTerm``'s ``fn``). The robot env ends
every task's episodes on ``non_finite`` (and, with ``terminate_on_cap_fault``, on ``cap_fault``); tracking
ends them on ``farther_than`` of its bodies' distances.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from bar_policy.quality.metrics import dwell_exceeded

__all__ = ["cap_fault", "farther_than", "non_finite"]


def non_finite(finite: jax.Array) -> jax.Array:
    """True when the physics state is not finite (``finite``: boolean scalar, every qpos and qvel finite)."""
    return jnp.logical_not(finite)


def farther_than(distance: jax.Array, limit: float) -> jax.Array:
    """True when any of ``distance`` (shape (B,), m) exceeds ``limit`` (m); never when ``limit`` is 0."""
    return (jnp.max(distance) > limit) & (limit > 0)


def cap_fault(time_at_cap: jax.Array) -> jax.Array:
    """True when any joint's unbroken time at its torque cap (s, shape (n,)) is past ``CAP_DWELL_S``.

    The deploy supervisor's saturation fault (``quality.metrics.dwell_exceeded``: the 26th tick of 20 ms at
    the cap), which ends a run on the robot in damping.
    """
    return jnp.any(dwell_exceeded(time_at_cap))
