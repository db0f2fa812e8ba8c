"""Reward terms of the reach task: small pure functions of arrays, positive "goodness" or positive "cost".

Every term returns a non-negative scalar; the sign lives only in the weight (``RewardScales``: rewards
positive, costs negative), and ``bar_policy.envs.reach`` logs each scaled term as ``reward/<name>``.
All functions are plain jnp arithmetic on unbatched inputs (vmap them for a batch).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "action_rate",
    "joint_limit",
    "joint_vel",
    "reach_kernel",
    "success",
    "torque",
]


def reach_kernel(dist_left: jax.Array, dist_right: jax.Array, std: float) -> jax.Array:
    """Mean over both hands of ``1 - tanh(d / std)``: 1 at the target, 0.24 at d = std, -> 0 far away.

    Args:
        dist_left: left fingertip-to-target distance, m, scalar.
        dist_right: right fingertip-to-target distance, m, scalar.
        std: length scale, m.
    """
    return 0.5 * ((1.0 - jnp.tanh(dist_left / std)) + (1.0 - jnp.tanh(dist_right / std)))


def success(dist_left: jax.Array, dist_right: jax.Array, radius: float) -> jax.Array:
    """1.0 when both fingertips are within ``radius`` (m) of their targets, else 0.0."""
    return jnp.logical_and(dist_left < radius, dist_right < radius).astype(jnp.float32)


def action_rate(action: jax.Array, last_action: jax.Array) -> jax.Array:
    """Cost ``sum((a_t - a_{t-1})^2)`` over joints, in action units (actions in [-1, 1])."""
    return jnp.sum(jnp.square(action - last_action))


def joint_limit(q: jax.Array, lower: jax.Array, upper: jax.Array, soft_fraction: float) -> jax.Array:
    """Cost: rad beyond the soft limits, summed over joints.

    The soft range is the joint range shrunk about its middle to ``soft_fraction`` of its width;
    ``sum(relu(q - soft_hi) + relu(soft_lo - q))``. Shapes: ``(n,)``, rad.
    """
    mid = 0.5 * (lower + upper)
    half = 0.5 * (upper - lower) * soft_fraction
    return jnp.sum(jnp.maximum(q - (mid + half), 0.0) + jnp.maximum((mid - half) - q, 0.0))


def torque(tau_sq_normalised: jax.Array) -> jax.Array:
    """Cost: ``sum((tau / tau_cap)^2)`` over joints, averaged over the substeps (computed in the scan).

    Dimensionless, in [0, n] with saturation on. Kept as a pass-through so the term has one named place.
    """
    return tau_sq_normalised


def joint_vel(dq: jax.Array) -> jax.Array:
    """Cost ``sum(dq^2)``, (rad/s)^2: damps needless motion and oscillation."""
    return jnp.sum(jnp.square(dq))
