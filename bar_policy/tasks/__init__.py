"""Task definitions shared by training and deployment (numpy only: no jax import at module level)."""

from bar_policy.tasks.reach import ReachTargetConfig, sample_targets

__all__ = ["ReachTargetConfig", "sample_targets"]
