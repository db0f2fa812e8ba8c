"""Reward terms of the tasks: small pure functions of arrays, positive "goodness" or positive "cost".

Every term returns a non-negative scalar; the sign lives only in the weight (a task's ``reward.scales``:
rewards positive, costs negative). A task's reward table (``tasks/<task>/term_table.py``, rows of
``envs.term_table.RewardTerm``) names these functions with their weights and parameters; the robot env
(``bar_policy.envs.robot``) sums the table and logs each scaled term as ``reward/<name>``. All functions
are plain jnp arithmetic on unbatched inputs (vmap them for a batch). Reach uses ``reach_kernel``,
``success``, ``joint_limit``, ``joint_deviation`` and ``joint_vel``; tracking uses ``joint_tracking``,
``body_pos_tracking`` and ``body_ori_tracking`` (with ``orientation_error``); every task uses
``action_rate``, ``action_accel`` and ``torque_near_cap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "action_accel",
    "action_rate",
    "body_ori_tracking",
    "body_pos_tracking",
    "joint_deviation",
    "joint_limit",
    "joint_tracking",
    "joint_vel",
    "orientation_error",
    "reach_kernel",
    "rotation_from_6d",
    "success",
    "torque",
    "torque_near_cap",
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


def action_accel(action: jax.Array, last_action: jax.Array, last_last_action: jax.Array) -> jax.Array:
    """Cost ``sum((a_t - 2 a_{t-1} + a_{t-2})^2)`` over joints, action units: the action's second difference.

    A high-pass of the action: its gain is ``(2 sin(pi f dt))^2``, 4 at the Nyquist frequency (25 Hz at
    50 Hz) and 0.016 at 1 Hz, so it penalises chatter and barely the motion itself.
    """
    return jnp.sum(jnp.square(action - 2.0 * last_action + last_last_action))


def joint_limit(q: jax.Array, lower: jax.Array, upper: jax.Array, soft_fraction: float) -> jax.Array:
    """Cost: rad beyond the soft limits, summed over joints.

    The soft range is the joint range shrunk about its middle to ``soft_fraction`` of its width;
    ``sum(relu(q - soft_hi) + relu(soft_lo - q))``. Shapes: ``(n,)``, rad.
    """
    mid = 0.5 * (lower + upper)
    half = 0.5 * (upper - lower) * soft_fraction
    return jnp.sum(jnp.maximum(q - (mid + half), 0.0) + jnp.maximum((mid - half) - q, 0.0))


def joint_deviation(q: jax.Array, q_ref: jax.Array) -> jax.Array:
    """Cost ``sum_j |q_j - q_ref_j|``, rad, over the joints given (shapes ``(n,)``).

    An L1 distance from a posture: it pulls as hard at 0.1 rad as at 0.5 rad, so it removes a habitual
    offset rather than only its far tail.
    """
    return jnp.sum(jnp.abs(q - q_ref))


def torque(tau_sq_normalised: jax.Array) -> jax.Array:
    """Cost: ``sum((tau / tau_cap)^2)`` over joints, averaged over the substeps (computed in the scan).

    Dimensionless, in [0, n] with saturation on. Kept as a pass-through so the term has one named place.
    """
    return tau_sq_normalised


def torque_near_cap(near_cap: jax.Array) -> jax.Array:
    """Cost: ``sum_j clip(|tau_law_j| / tau_cap_j - 0.8, 0, 1)``, averaged over the substeps (in the scan).

    The unclipped MIT demand beyond 80 % of each cap (``Transition.near_cap``), dimensionless, <= n. Kept
    as a pass-through so the term has one named place.
    """
    return near_cap


def joint_vel(dq: jax.Array) -> jax.Array:
    """Cost ``sum(dq^2)``, (rad/s)^2: damps needless motion and oscillation."""
    return jnp.sum(jnp.square(dq))


# ---------------------------------------------------------------------------------------------------
# Tracking
# ---------------------------------------------------------------------------------------------------
def joint_tracking(q: jax.Array, q_ref: jax.Array, std: float) -> jax.Array:
    """``exp(-mean_j (q_j - q_ref_j)^2 / std^2)``: 1 on the reference, exp(-1) at an RMS error of ``std``.

    Shapes ``(n,)``, rad; ``std`` in rad.
    """
    return jnp.exp(-jnp.mean(jnp.square(q - q_ref)) / std**2)


def body_pos_tracking(pos: jax.Array, pos_ref: jax.Array, std: float) -> jax.Array:
    """``exp(-mean_b |p_b - p_ref_b|^2 / std^2)`` over the tracked bodies.

    Shapes ``(B, 3)``, m; ``std`` in m.
    """
    return jnp.exp(-jnp.mean(jnp.sum(jnp.square(pos - pos_ref), axis=-1)) / std**2)


def rotation_from_6d(ori6: jax.Array) -> jax.Array:
    """Rotation matrices from the 6-D form ``(r00, r01, r10, r11, r20, r21)`` (columns 0-1, row-major).

    The third column is the cross product of the first two (exact for the rotation matrices the reference
    table stores). Shape ``(..., 6) -> (..., 3, 3)``.
    """
    c = ori6.reshape(*ori6.shape[:-1], 3, 2)
    c2 = jnp.cross(c[..., 0], c[..., 1])
    return jnp.concatenate([c, c2[..., None]], axis=-1)


def orientation_error(rot: jax.Array, rot_ref: jax.Array) -> jax.Array:
    """Geodesic angle between rotation matrices, rad, in [0, pi]. Shapes ``(..., 3, 3) -> (...)``.

    Uses ``||R - R_ref||_F = 2 sqrt(2) sin(theta / 2)`` (arcsin of a clipped argument: no NaN at theta = 0
    or for slightly non-orthogonal float32 input, unlike ``arccos((trace - 1) / 2)``).
    """
    fro = jnp.sqrt(jnp.sum(jnp.square(rot - rot_ref), axis=(-2, -1)))
    return 2.0 * jnp.arcsin(jnp.clip(fro / (2.0 * jnp.sqrt(2.0)), 0.0, 1.0))


def body_ori_tracking(rot: jax.Array, ori6_ref: jax.Array, std: float) -> jax.Array:
    """``exp(-mean_b theta_b^2 / std^2)`` with ``theta_b`` = ``orientation_error`` of each tracked body.

    Args:
        rot: body rotation matrices, shape ``(B, 3, 3)``.
        ori6_ref: reference orientations in 6-D form, shape ``(B, 6)``.
        std: angle scale, rad.
    """
    theta = orientation_error(rot, rotation_from_6d(ori6_ref))
    return jnp.exp(-jnp.mean(jnp.square(theta)) / std**2)
