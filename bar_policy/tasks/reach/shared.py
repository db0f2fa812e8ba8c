"""Bimanual reach: the target distribution, shared by the MJX env (jax) and deploy command sources (numpy).

Each fingertip (site ``left_finger2_tip`` / ``right_finger2_tip``) has its own target, a point in the chest
frame sampled uniformly in a box in front of the chest. The right box is the mirror image (y -> -y) of the
left one. The boxes surround the piano-ready fingertips (0.361, +-0.159, 0.21) m and stay inside the arm's
reach (shoulder centre at (0, +-0.09, 0.39) m, shoulder-to-fingertip 0.615 m); ``tests/test_reach_task.py``
checks with C MuJoCo IK that every corner is reachable.

``sample_targets`` is written on uniform variates so the env draws them with ``jax.random.uniform`` and the
deploy side with ``numpy.random.Generator.random``: same distribution, same code.

**Command transition.** A new target is not shown to the policy as a step: the commanded target moves from
where it was to the new one along a minimum-jerk path over ``transition_s`` (``transition_point``), the way
a robot arm's setpoint generator moves between waypoints. A step asks for an infinitely fast move, and the
policy answers with a command whose content above 5 Hz is chatter by definition (a 0.5 rad step
through the 3 Hz action filter alone measures 10.8 mrad; the same move as a 1 s minimum-jerk path, 0.25).
The env (jax) and every deploy command source (numpy) call this same function; the ONNX metadata key
``bar.command_transition`` carries the duration (absent: 0, a step, as in files made before it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bar_policy._array import Array, array_namespace

__all__ = ["SUCCESS_RADIUS", "ReachTargetConfig", "min_jerk", "sample_targets", "transition_point"]

SUCCESS_RADIUS = 0.03
"""A hand has reached its target when the fingertip is within this distance, m."""


@dataclass(frozen=True, kw_only=True)
class ReachTargetConfig:
    """Target workspace of the LEFT fingertip, chest frame, m; the right one mirrors y."""

    x_range: tuple[float, float] = (0.22, 0.42)
    """Forward distance from the chest origin, m."""
    y_range: tuple[float, float] = (0.08, 0.30)
    """Lateral distance (left positive), m; the right hand uses (-hi, -lo)."""
    z_range: tuple[float, float] = (0.12, 0.40)
    """Height above the chest origin (the stand's base), m."""

    def __post_init__(self) -> None:
        for name in ("x_range", "y_range", "z_range"):
            lo, hi = getattr(self, name)
            if not lo <= hi:
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        if self.y_range[0] <= 0.035:
            raise ValueError(
                f"y_range low {self.y_range[0]} m lets the two hands' targets overlap; keep it > 0.035 m"
            )

    @property
    def low(self) -> np.ndarray:
        """Lower corner of the left box, shape (3,)."""
        return np.array([self.x_range[0], self.y_range[0], self.z_range[0]])

    @property
    def high(self) -> np.ndarray:
        """Upper corner of the left box, shape (3,)."""
        return np.array([self.x_range[1], self.y_range[1], self.z_range[1]])


def sample_targets(u: Array, cfg: ReachTargetConfig) -> tuple[Array, Array]:
    """Map uniform variates to (left, right) targets.

    Args:
        u: uniform [0, 1) variates, shape ``(..., 6)``: 3 for the left target, 3 for the right.
        cfg: the workspace.

    Returns:
        ``(left, right)``, each shape ``(..., 3)``, chest frame, m; numpy or jax like ``u``.
    """
    xp = array_namespace(u)
    lo = xp.asarray(cfg.low, dtype=u.dtype)
    hi = xp.asarray(cfg.high, dtype=u.dtype)
    mirror = xp.asarray([1.0, -1.0, 1.0], dtype=u.dtype)
    left = lo + u[..., :3] * (hi - lo)
    right = (lo + u[..., 3:6] * (hi - lo)) * mirror
    return left, right


def min_jerk(s: Array) -> Array:
    """The minimum-jerk profile ``10 s^3 - 15 s^4 + 6 s^5`` of a phase ``s`` clipped to [0, 1].

    0 at ``s <= 0`` and 1 at ``s >= 1``, with zero velocity and acceleration at both ends (Flash & Hogan,
    1985); shape of ``s``, numpy or jax.
    """
    xp = array_namespace(s)
    s = xp.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def transition_point(start: Array, goal: Array, elapsed_s: Array | float, duration_s: float) -> Array:
    """The commanded target ``elapsed_s`` s into a move from ``start`` to ``goal`` lasting ``duration_s``.

    ``start + (goal - start) * min_jerk(elapsed / duration)``; ``duration_s <= 0`` is a step (``goal`` at
    once). Shapes: ``start``/``goal`` ``(..., 3)`` m, ``elapsed_s`` scalar or ``(...)`` s (broadcast on the
    last axis); numpy or jax like ``goal``.
    """
    if duration_s <= 0:
        return goal
    xp = array_namespace(goal)
    s = min_jerk(xp.asarray(elapsed_s, dtype=goal.dtype) / duration_s)
    return start + (goal - start) * s[..., None]
