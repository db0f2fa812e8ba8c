"""Sim2sim evaluation of a reach policy: the ONNX policy on the C MuJoCo ``sim`` target over seeded episodes.

``bar-deploy eval`` runs it for reach policies (``tasks.reach.deploy``); tracking policies have their own
metric (``tasks.track.evaluate``).

The protocol mirrors the LiteReach env's (``bar_policy.tasks.reach.env``; defaults of ``ReachEnvConfig``):

- an episode lasts ``episode_length`` = 5 s (250 control ticks at 50 Hz) and starts at the default pose
  (``piano_ready``) plus U(-init_noise, init_noise) per joint (clipped to the limits; 0 by default, as the
  env's nominal evaluation config), at rest;
- the targets come from ``SampledCommands(seed + e)`` (``tasks.reach.shared.sample_targets``, the training
  distribution) and are resampled every ``resample_period`` = 2.5 s: two target segments per episode; a
  file trained with a command transition sees each new target arrive along the env's minimum-jerk path
  (``tasks.reach.transition``), starting at the default pose's fingertips;
- success is scored at the last control tick of every target segment (after that tick's physics): both
  fingertips within ``SUCCESS_RADIUS`` (3 cm) of the segment's targets, as the env's
  ``success_end / segment_end`` metric; a segment ending after a fault fails. The success rate is
  ``successful segments / segments``.

The episodes run on the runner ``bar-deploy eval`` hands in (``tasks.episodes.EpisodeRunner``; the runtime's
``deploy.episodes.SimEpisodes``): the sim integrates the law's damping as the policy was trained (implicit
unless the file's randomisation record says explicit), and the policy runs from the first tick (no ramp)
through exactly the deploy code path: ``Runtime`` with the observation manager, the action clip, the safety
supervisor and the firmware MIT law in the sim. The env's
randomisation (latency, gains, encoder offset, observation noise) is not modelled here: compare with the MJX
evaluation of the nominal config.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bar_policy.quality import EpisodeQuality, summarise
from bar_policy.quality.report import quality_summary_line
from bar_policy.robot.kinematics import Kinematics
from bar_policy.tasks.episodes import EpisodeRunner, Policy, report_progress, true_q
from bar_policy.tasks.interfaces import EvalReport
from bar_policy.tasks.reach.commands import SampledCommands
from bar_policy.tasks.reach.shared import SUCCESS_RADIUS
from bar_policy.tasks.reach.transition import with_transition

__all__ = ["EpisodeResult", "EvalConfig", "EvalResult", "evaluate"]


@dataclass(frozen=True, kw_only=True)
class EvalConfig:
    """Episode protocol of the sim2sim evaluation."""

    episodes: int = 100
    """Number of episodes."""
    seed: int = 0
    """Seed of episode 0; episode e uses seed + e (targets and initial noise)."""
    episode_length: float = 5.0
    """Episode length, s (250 control ticks at 50 Hz; ``ReachEnvConfig.episode_length_s``)."""
    resample_period: float | None = 2.5
    """Target resampling period, s (``ReachEnvConfig.resample_period_s``); None: one segment per episode."""
    success_radius: float = SUCCESS_RADIUS
    """Both fingertips within this distance of their targets at a segment's end, m."""
    initial_pose: str = "piano_ready"
    """Pose each episode starts from (at rest)."""
    init_noise: float = 0.0
    """Half-width of the uniform initial joint noise around the pose, rad (env nominal config: 0)."""

    def __post_init__(self) -> None:
        if self.episodes < 1:
            raise ValueError(f"EvalConfig.episodes must be >= 1, got {self.episodes}")
        if not (math.isfinite(self.episode_length) and self.episode_length > 0):
            raise ValueError(f"EvalConfig.episode_length must be > 0 s, got {self.episode_length}")
        if self.resample_period is not None and not self.resample_period > 0:
            raise ValueError(f"EvalConfig.resample_period must be > 0 s or None, got {self.resample_period}")
        if not self.init_noise >= 0:
            raise ValueError(f"EvalConfig.init_noise must be >= 0 rad, got {self.init_noise}")


@dataclass(frozen=True)
class EpisodeResult:
    """One episode."""

    seed: int
    segments: int
    """Target segments scored."""
    successes: int
    """Segments that ended with both fingertips within the radius."""
    dist_left: list[float]
    """Left fingertip-to-target distance at each segment end, m."""
    dist_right: list[float]
    """Right fingertip-to-target distance at each segment end, m."""
    faulted: bool
    end_reason: str
    quality: dict[str, Any] = field(default_factory=dict)
    """The episode's safety and smoothness (``EpisodeQuality.to_dict``)."""


@dataclass(frozen=True)
class EvalResult(EvalReport):
    """All episodes and the success rate."""

    config: EvalConfig
    episodes: list[EpisodeResult]
    policy: str
    fingerprint: str
    target: str = "C MuJoCo sim target"
    """The episodes' target (``EpisodeRunner.target_label``, or the class of the one given)."""

    @property
    def segments(self) -> int:
        """Target segments scored over all episodes."""
        return sum(e.segments for e in self.episodes)

    @property
    def success_rate(self) -> float:
        """Successful segments / segments (the env's ``success_end / segment_end``)."""
        return sum(e.successes for e in self.episodes) / max(self.segments, 1)

    def wilson_interval(self, z: float = 1.96) -> tuple[float, float]:
        """95 % Wilson score interval of the success rate (segments treated as independent trials)."""
        n = max(self.segments, 1)
        p = self.success_rate
        centre = (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        return max(centre - half, 0.0), min(centre + half, 1.0)

    def to_dict(self) -> dict[str, Any]:
        """JSON form."""
        lo, hi = self.wilson_interval()
        return {
            "policy": self.policy,
            "obs_fingerprint": self.fingerprint,
            "target": self.target,
            "config": asdict(self.config),
            "success_rate": self.success_rate,
            "wilson95": [lo, hi],
            "episodes": [asdict(e) for e in self.episodes],
            "gate_report": self.gate_report(),
        }

    def median_end_cm(self) -> float | None:
        """Median of every segment end's fingertip distance over both hands, cm (None: no segment)."""
        dists = [np.asarray(d, float) for e in self.episodes for d in (e.dist_left, e.dist_right) if len(d)]
        return float(np.median(np.concatenate(dists))) * 100.0 if dists else None

    def gate_report(self) -> dict[str, Any]:
        """The ship gate's input: segment success %, median end distance, the episodes' quality."""
        records = [EpisodeQuality.from_dict(e.quality) for e in self.episodes if e.quality]
        return {
            "task": "reach",
            "quality": summarise(records),
            "episodes": [r.to_dict() for r in records],
            "success_pct": 100.0 * self.success_rate,
            "median_end_cm": self.median_end_cm(),
        }

    def format(self) -> str:
        """Summary lines."""
        c = self.config
        lo, hi = self.wilson_interval()
        dl = np.concatenate([e.dist_left for e in self.episodes])
        dr = np.concatenate([e.dist_right for e in self.episodes])
        return "\n".join(
            [
                f"sim2sim ({self.target}) policy {self.policy} [{self.fingerprint}]",
                f"episodes {len(self.episodes)} (seeds {c.seed}..{c.seed + len(self.episodes) - 1}), "
                f"length {c.episode_length:g} s, resample "
                f"{'none' if c.resample_period is None else f'{c.resample_period:g} s'}, init noise "
                f"{c.init_noise:g} rad; success = both fingertips within {c.success_radius * 100:g} cm "
                f"at a segment's end",
                f"success rate {self.success_rate * 100:.1f} % of {self.segments} segments "
                f"(95 % CI {lo * 100:.1f}-{hi * 100:.1f} %), faults {sum(e.faulted for e in self.episodes)}",
                f"segment-end distance left median {np.median(dl) * 100:.1f} cm, "
                f"right median {np.median(dr) * 100:.1f} cm",
                quality_summary_line(self.gate_report()["quality"]),
                *self.gate_lines(),
            ]
        )


def evaluate(
    policy: Policy, config: EvalConfig | None = None, target: Any = None, *, runner: EpisodeRunner
) -> EvalResult:
    """Run the episodes on ``target`` (default: ``runner.target()``); see the module docstring."""
    cfg = config or EvalConfig()
    sim = target or runner.target(initial_pose=cfg.initial_pose)
    kin = Kinematics(policy.robot.mode)
    names = policy.obs_manager.command_names
    q0 = policy.robot.pose(cfg.initial_pose)
    tips0 = kin.fingertips(np.asarray(policy.default_joint_pos))
    initial = {"target_pos_left": tips0[0], "target_pos_right": tips0[1]}
    n_ticks = round(cfg.episode_length / policy.policy_dt)
    seg_ticks = n_ticks if cfg.resample_period is None else round(cfg.resample_period / policy.policy_dt)
    robot = policy.robot
    results = []
    for e in range(cfg.episodes):
        seed = cfg.seed + e
        rng = np.random.default_rng(seed)
        q = q0 + rng.uniform(-cfg.init_noise, cfg.init_noise, q0.shape) if cfg.init_noise > 0 else q0
        sim.reset(np.clip(q, robot.lower, robot.upper))
        commands = with_transition(
            SampledCommands(names, seed=seed, period=seg_ticks * policy.policy_dt), policy, initial
        )
        dists: list[tuple[float, float]] = []

        def score(k: int, t: float, rt: Any, dists: list[tuple[float, float]] = dists) -> None:
            if (k + 1) % seg_ticks == 0 or k + 1 == n_ticks:
                left, right = kin.fingertips(true_q(sim))
                dl = float(np.linalg.norm(left - rt.last_commands["target_pos_left"]))
                dr = float(np.linalg.norm(right - rt.last_commands["target_pos_right"]))
                faulted = rt.safety.fault_count > 0
                dists.append((dl, dr) if not faulted else (math.inf, math.inf))

        res = runner.run(sim, commands, cfg.episode_length, kinematics=kin, on_tick=score)
        faulted = res.fault_count > 0
        n_segments = n_ticks // seg_ticks + (1 if n_ticks % seg_ticks else 0)
        dists += [(math.inf, math.inf)] * (n_segments - len(dists))  # segments cut short by a fault fail
        ok = [dl < cfg.success_radius and dr < cfg.success_radius for dl, dr in dists]
        ok_count, n_seg = int(sum(ok)), len(dists)
        fault = ", faulted" if faulted else ""
        worst = max(max(d) for d in dists) if dists else math.inf
        figure = (
            f"seed {seed}, {ok_count}/{n_seg} segments reached, farthest segment end "
            f"{worst * 100:.1f} cm{fault}"
        )
        report_progress(runner, "episode", e + 1, cfg.episodes, figure)
        results.append(
            EpisodeResult(
                seed=seed,
                segments=len(dists),
                successes=int(sum(ok)),
                dist_left=[d[0] for d in dists],
                dist_right=[d[1] for d in dists],
                faulted=faulted,
                end_reason=res.end_reason,
                quality={**res.quality["episode"], "name": f"episode-{seed}"},
            )
        )
    return EvalResult(
        config=cfg,
        episodes=results,
        policy=str(policy.path),
        fingerprint=policy.obs_manager.fingerprint,
        target=runner.target_label if target is None else type(target).__name__,
    )
