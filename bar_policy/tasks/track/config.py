"""Configuration of LiteTrack: the robot env's config plus the motion reference, reward and termination."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.motion.library import CLIP_SETS

__all__ = [
    "AdaptiveSamplingConfig",
    "MotionConfig",
    "TrackEnvConfig",
    "TrackRewardConfig",
    "TrackRewardScales",
    "default_config",
    "heldout_config",
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
    fingertip_pos: float = 1.0
    """Weight of ``exp(-mean_f |p - p_ref|^2 / fingertip_std^2)`` over both fingertips (precision at the
    end of the chain, where joint errors add up)."""
    action_rate: float = -0.1
    """Weight of ``sum((a_t - a_{t-1})^2)`` of the applied action (action units); BeyondMimic's -0.1."""
    action_accel: float = -0.2
    """Weight of ``sum((a_t - 2 a_{t-1} + a_{t-2})^2)`` of the applied action (action units): chatter's
    own penalty (a high-pass; the first GPU run chattered at 5 mrad mean, 35 worst, as it got precise)."""
    torque: float = -0.005
    """Weight of ``sum((tau / tau_cap)^2)`` averaged over substeps."""
    torque_near_cap: float = -0.1
    """Weight of ``sum_j clip(|tau_law_j| / tau_cap_j - 0.8, 0, 1)`` of the unclipped MIT demand, averaged
    over substeps (``Transition.near_cap``): the last 20 % before a joint saturates, and what it asks
    beyond, up to 1.8 caps."""


@dataclass(frozen=True, kw_only=True)
class TrackRewardConfig:
    """Reward shaping of the tracking task."""

    scales: TrackRewardScales = field(default_factory=TrackRewardScales)
    """Term weights."""
    joint_std: float = 0.08
    """RMS joint error at which the joint term is exp(-1), rad (0.15 in the v3 recipe; 0.08 took the
    held-out error from 0.0227 to 0.0175 rad at the same budget, docs/tracking.md)."""
    body_pos_std: float = 0.06
    """RMS body position error at which the body position term is exp(-1), m."""
    body_ori_std: float = 0.3
    """RMS body orientation error at which the orientation term is exp(-1), rad."""
    fingertip_std: float = 0.01
    """RMS fingertip position error at which the fingertip term is exp(-1), m (the 1 cm target sits on its
    steepest part, where the kernel's slope peaks: 0.5 cm gives 0.78, 1 cm 0.37, 2 cm 0.02)."""

    def __post_init__(self) -> None:
        stds = (self.joint_std, self.body_pos_std, self.body_ori_std, self.fingertip_std)
        if not all(x > 0 for x in stds):
            raise ValueError(
                f"kernel stds must be > 0, got joint_std={self.joint_std} rad, "
                f"body_pos_std={self.body_pos_std} m, body_ori_std={self.body_ori_std} rad, "
                f"fingertip_std={self.fingertip_std} m"
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
class AdaptiveSamplingConfig:
    """Where training episodes start: more often just before the clip segments where episodes fail.

    The training clips are cut into bins of ``bin_s``; the batched wrapper keeps, per device, a decaying
    count of the env steps spent in each bin and of the episodes that ended there by the task's termination
    (a lost reference). A reset draws its start bin with probability ``uniform_share / B`` plus
    ``(1 - uniform_share)`` times the bins' failure rates smoothed towards the bins before them (a failure
    in bin b also raises bins b - 1 .. b - kernel_bins + 1 of the same clip, weighted ``kernel_decay^k``, so
    episodes start early enough to approach the hard part), normalised; then a start frame uniformly in the
    bin. With no failure yet, starts are uniform over bins. BeyondMimic samples its motions this way.
    """

    enabled: bool = True
    """Off: starts are uniform over frames (the env's own reset)."""
    bin_s: float = 1.0
    """Bin length, s."""
    uniform_share: float = 0.2
    """Share of starts drawn uniformly over the bins."""
    decay: float = 0.999
    """Per batched step, the factor on the counts (the statistics' memory is about 1 / (1 - decay) steps)."""
    kernel_bins: int = 3
    """A failure raises this many bins: its own and the ones before it."""
    kernel_decay: float = 0.8
    """Weight ratio between consecutive bins of the kernel."""

    def __post_init__(self) -> None:
        if not (self.bin_s > 0 and 0 <= self.uniform_share <= 1 and 0 < self.decay < 1):
            raise ValueError(
                f"adaptive sampling needs bin_s > 0 s, 0 <= uniform_share <= 1, 0 < decay < 1, got "
                f"{self.bin_s}, {self.uniform_share}, {self.decay}"
            )
        if self.kernel_bins < 1 or not 0 < self.kernel_decay <= 1:
            raise ValueError(
                f"kernel_bins must be >= 1 and 0 < kernel_decay <= 1, got {self.kernel_bins}, "
                f"{self.kernel_decay}"
            )


@dataclass(frozen=True, kw_only=True)
class TrackEnvConfig(RobotEnvConfig):
    """Everything LiteTrack needs. Build with ``default_config()``; derive with ``dataclasses.replace``."""

    episode_length_s: float = 10.0
    """Episode length, s (500 control steps)."""
    action_scale: float | tuple[float, ...] | None = None
    """Rad per unit action; None: the tracking layout's per-joint scale (``shared.track_action_scale``:
    half the motion box plus 0.25 rad)."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """The reference clips."""
    reward: TrackRewardConfig = field(default_factory=TrackRewardConfig)
    """Reward terms and weights."""
    termination_distance: float = 0.25
    """The episode ends when any tracked body is farther than this from its reference, m (0 disables)."""
    sampling: AdaptiveSamplingConfig = field(default_factory=AdaptiveSamplingConfig)
    """Where training episodes start (the batched wrapper's auto-reset)."""
    action_filter_hz: float | None = 3.0
    """Cutoff of the action low-pass, Hz (``RobotEnvConfig.action_filter_hz``): -8 dB at 7 Hz, -18 dB at the
    25 Hz limit cycle of earlier trackers; 53 ms of lag, inside the 100 ms lookahead. Measured on one H100
    at the same 9 min budget (docs/tracking.md): 3 Hz held-out 0.0156 rad / 1.03 cm, 4 Hz 0.0171 / 1.22,
    10 Hz 0.045 / 2.57 (the smoothed exploration noise is what lets PPO find the precise policy)."""

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


def heldout_config(base: TrackEnvConfig | None = None) -> TrackEnvConfig:
    """``base`` (default: ``default_config()``) on the held-out clips with uniform starts.

    What the trainer's evaluation runs: never the training clips.
    """
    cfg = base or default_config()
    return replace(
        cfg, motion=replace(cfg.motion, clip_set="heldout"), sampling=replace(cfg.sampling, enabled=False)
    )
