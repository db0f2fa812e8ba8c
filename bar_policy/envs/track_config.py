"""Configuration of LiteTrack: the robot env's config plus the motion reference, reward and termination."""

from __future__ import annotations

from dataclasses import dataclass, field

from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.motion.library import CLIP_SETS

__all__ = [
    "MotionConfig",
    "TrackEnvConfig",
    "TrackRewardConfig",
    "TrackRewardScales",
    "default_config",
    "nominal_config",
]


@dataclass(frozen=True, kw_only=True)
class TrackRewardScales:
    """Weights of the tracking reward terms (positive: reward, negative: cost), per control step."""

    joint_pos: float = 1.0
    """Weight of ``exp(-mean_j (q - q_ref)^2 / joint_std^2)``."""
    body_pos: float = 1.0
    """Weight of ``exp(-mean_b |p - p_ref|^2 / body_pos_std^2)`` over the tracked bodies."""
    body_ori: float = 0.5
    """Weight of ``exp(-mean_b theta^2 / body_ori_std^2)``, theta = orientation error of each tracked body."""
    action_rate: float = -0.005
    """Weight of ``sum((a_t - a_{t-1})^2)`` (action units)."""
    torque: float = -0.005
    """Weight of ``sum((tau / tau_cap)^2)`` averaged over substeps."""


@dataclass(frozen=True, kw_only=True)
class TrackRewardConfig:
    """Reward shaping of the tracking task."""

    scales: TrackRewardScales = field(default_factory=TrackRewardScales)
    """Term weights."""
    joint_std: float = 0.15
    """RMS joint error at which the joint term is exp(-1), rad."""
    body_pos_std: float = 0.06
    """RMS body position error at which the body position term is exp(-1), m."""
    body_ori_std: float = 0.3
    """RMS body orientation error at which the orientation term is exp(-1), rad."""

    def __post_init__(self) -> None:
        if not (self.joint_std > 0 and self.body_pos_std > 0 and self.body_ori_std > 0):
            raise ValueError(
                f"kernel stds must be > 0, got joint_std={self.joint_std} rad, "
                f"body_pos_std={self.body_pos_std} m, body_ori_std={self.body_ori_std} rad"
            )


@dataclass(frozen=True, kw_only=True)
class MotionConfig:
    """Which clips the reference frames come from (``bar_policy.motion.library.clip_set``)."""

    clip_set: str = "train"
    """``train`` (random clips, seed 0), ``heldout`` (random clips, seed 1, plus the gestures) or
    ``gestures``."""
    num_clips: int | None = None
    """Random clips in the set (None: the library's default, ``CLIP_SETS``)."""
    clip_length_s: float = 30.0
    """Duration of each random clip, s."""

    def __post_init__(self) -> None:
        if self.clip_set not in CLIP_SETS:
            raise ValueError(f"unknown clip set {self.clip_set!r}; clip sets: {sorted(CLIP_SETS)}")
        if self.num_clips is not None and self.num_clips < (0 if self.clip_set == "gestures" else 1):
            raise ValueError(f"num_clips must be >= 1 for clip set {self.clip_set!r}, got {self.num_clips}")
        if not self.clip_length_s > 0:
            raise ValueError(f"clip_length_s must be > 0 s, got {self.clip_length_s}")


@dataclass(frozen=True, kw_only=True)
class TrackEnvConfig(RobotEnvConfig):
    """Everything LiteTrack needs. Build with ``default_config()``; derive with ``dataclasses.replace``."""

    episode_length_s: float = 10.0
    """Episode length, s (500 control steps)."""
    action_scale: float | tuple[float, ...] | None = None
    """Rad per unit action; None: the tracking layout's per-joint scale (``tasks.track.track_action_scale``:
    half the motion box plus 0.25 rad)."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """The reference clips."""
    reward: TrackRewardConfig = field(default_factory=TrackRewardConfig)
    """Reward terms and weights."""
    termination_distance: float = 0.25
    """The episode ends when any tracked body is farther than this from its reference, m (0 disables)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.termination_distance >= 0:
            raise ValueError(f"termination_distance must be >= 0 m, got {self.termination_distance}")


def default_config() -> TrackEnvConfig:
    """The training configuration: random training clips, every actuator effect and randomisation on."""
    return TrackEnvConfig()


def nominal_config(base: TrackEnvConfig | None = None) -> TrackEnvConfig:
    """``base`` (default: ``default_config()``) with every randomisation and noise off."""
    return nominal(base or default_config())
