"""Bimanual reach: the target distribution, shared by the MJX env (jax) and deploy command sources (numpy).

Each fingertip (site ``left_finger2_tip`` / ``right_finger2_tip``) has its own target, a point in the chest
frame sampled uniformly in a box in front of the chest. The right box is the mirror image (y -> -y) of the
left one. The boxes surround the piano-ready fingertips (0.361, +-0.159, 0.21) m and stay inside the arm's
reach (shoulder centre at (0, +-0.09, 0.39) m, shoulder-to-fingertip 0.615 m); ``tests/test_reach_task.py``
checks with C MuJoCo IK that every corner is reachable.

``sample_targets`` is written on uniform variates so the env draws them with ``jax.random.uniform`` and the
deploy side with ``numpy.random.Generator.random``: same distribution, same code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bar_policy._array import Array, array_namespace

__all__ = ["SUCCESS_RADIUS", "ReachTargetConfig", "sample_targets"]

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
