"""Piano reward terms (placeholder until the reviewed module lands): pure jax/numpy functions."""

from __future__ import annotations

from bar_policy._array import Array, array_namespace

__all__ = ["energy", "fingertip_near", "key_press", "wrong_keys"]


def key_press(angles: Array, goal: Array, threshold: Array, angle_max: Array) -> Array:
    """Mean over goal keys of ``clip(angle / threshold, 0, 1)``; 0 when no key is a goal. Shapes (n_keys,)."""
    xp = array_namespace(angles)
    depth = xp.clip(angles / threshold, 0.0, 1.0)
    n = xp.sum(goal)
    return xp.where(n > 0, xp.sum(depth * goal) / xp.maximum(n, 1.0), 0.0)


def wrong_keys(down: Array, goal: Array) -> Array:
    """Share of the keyboard's keys that are down and not goals. Shapes (n_keys,)."""
    xp = array_namespace(goal)
    return xp.mean(down.astype(goal.dtype) * (1.0 - goal))


def fingertip_near(tips: Array, key_pos: Array, goal: Array, std: float) -> Array:
    """Mean over goal keys of ``1 - tanh(d / std)``, d the distance to the nearest fingertip, m.

    Shapes: ``tips`` (2, 3), ``key_pos`` (n_keys, 3), ``goal`` (n_keys,). 0 when no key is a goal.
    """
    xp = array_namespace(key_pos)
    d = xp.min(xp.linalg.norm(key_pos[:, None, :] - tips[None, :, :], axis=-1), axis=1)
    k = 1.0 - xp.tanh(d / std)
    n = xp.sum(goal)
    return xp.where(n > 0, xp.sum(k * goal) / xp.maximum(n, 1.0), 0.0)


def energy(tau: Array, dq: Array) -> Array:
    """``sum |tau * dq|``, W. Shapes (n,)."""
    xp = array_namespace(tau)
    return xp.sum(xp.abs(tau * dq))
