"""LiteReach: each fingertip of the Lite to its own target (a task on the robot env, ``robot.py``).

Semantics (fixed; the exported policy and the deploy runtime rely on them). Action, control, latency,
noise and the initial-state noise are the robot env's (``bar_policy.envs.robot``); the task adds:

- **Action**: ``q_cmd = clip(default_pose + action_scale * a, lower, upper)`` with ``default_pose`` =
  ``piano_ready`` (the layout's ``default_joint_pos``), ``action_scale`` = 0.8 rad for every joint and ``a``
  the policy's action low-passed at ``action_filter_hz`` (3 Hz; the deploy runtime applies the same).
- **Observation**: ``ObservationManager.for_task("reach", mode)`` (54 entries for arms): measured q, dq,
  previous action, fingertip positions by forward kinematics of the measured q (chest frame = world frame,
  the chest is the fixed root), and the two targets.
- **Task**: targets from ``bar_policy.tasks.reach.shared.sample_targets`` at reset and every
  ``resample_period_s``. The commanded target (observed, rewarded, scored) moves to each new target along
  ``transition_point``'s minimum-jerk path over ``target_transition_s``, from the previous commanded target
  (at reset: the fingertips of the default pose, where the deploy runtime's HOLD ramp leaves them).
  Success = both fingertips within ``SUCCESS_RADIUS`` (3 cm). Rewards are the rows of the task's term
  table (``term_table.py``: functions of ``bar_policy.envs.rewards``) weighted by ``RewardScales``. The
  reward uses the true fingertip positions from the last substep's kinematics (2 ms before the step's
  end, saving one FK pass).
- **Episodes**: the env ends an episode only when the physics state turns non-finite; the wrappers truncate
  at ``episode_length`` = ``episode_length_s / ctrl_dt`` steps.
- **Metrics** (per step; brax sums them per episode): ``reward/<term>``, ``dist_left``, ``dist_right``
  (m), ``success`` (both hands in 3 cm now), ``segment_end`` (1 on the last step of a target segment) and
  ``success_end`` (success on that step). Success rate = sum(success_end) / sum(segment_end).
- **Initial state**: default pose + U(-init_noise, init_noise) per joint (clipped to the limits), zero
  velocity.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from bar_policy.envs import rewards
from bar_policy.envs.device_arrays import to_device
from bar_policy.envs.robot import LiteRobotEnv
from bar_policy.envs.robot_config import (
    ActuatorConfig,
    ModelRandomizationConfig,
    ObsNoiseConfig,
    RobotEnvConfig,
    check_multiple,
    nominal,
)
from bar_policy.envs.site_kinematics import plan_sites, site_positions
from bar_policy.envs.task import TaskStep, Transition
from bar_policy.envs.term_table import RewardTerm, TerminationTerm
from bar_policy.obs import ObservationManager
from bar_policy.robot.constants import FINGERTIP_SITES
from bar_policy.robot.kinematics import Kinematics
from bar_policy.robot.scene import SceneEdit
from bar_policy.tasks.reach import term_table
from bar_policy.tasks.reach.shared import SUCCESS_RADIUS, ReachTargetConfig, sample_targets, transition_point
from bar_policy.tasks.reach.term_table import RewardConfig, RewardScales

__all__ = [
    "ActuatorConfig",
    "LiteReach",
    "ModelRandomizationConfig",
    "ObsNoiseConfig",
    "ReachEnvConfig",
    "RewardConfig",
    "RewardScales",
    "default_config",
    "neck_config",
    "nominal_config",
]


FINGERTIP_KINEMATICS = ("chains", "mjx")
"""``ReachEnvConfig.fingertip_kinematics``'s choices."""


@dataclass(frozen=True, kw_only=True)
class ReachEnvConfig(RobotEnvConfig):
    """Everything LiteReach needs. Build with ``default_config()``; derive with ``dataclasses.replace``."""

    resample_period_s: float = 2.5
    """Targets are resampled every this many s, s (a multiple of ctrl_dt)."""
    action_filter_hz: float | None = 3.0
    """Cutoff of the action low-pass, Hz (``RobotEnvConfig.action_filter_hz``), the tracker's: PPO's
    exploration noise reaches the joints smoothed, and the deploy runtime applies the same filter."""
    target_transition_s: float = 1.0
    """Duration of the commanded target's minimum-jerk move to each new target, s (0: a step, the
    original design). A step measured 14.9 mrad of chatter on q_cmd through the 3 Hz filter
    (docs/training.md); a 1 s move leaves 1.5 s of the 2.5 s segment to settle inside the 3 cm success
    radius."""
    target: ReachTargetConfig = field(default_factory=ReachTargetConfig)
    """Target workspace (chest frame)."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """Reward terms and weights."""
    fingertip_kinematics: str = "chains"
    """How the observation's fingertips are computed from the measured q (``FINGERTIP_KINEMATICS``):
    ``chains``, the two arms' body chains alone (``envs.site_kinematics``), or ``mjx``, ``mjx.kinematics``
    of every frame. The same positions to float32 rounding (tests/envs/test_site_kinematics.py); ``chains``
    traces in a fraction of the time, on a cold start's critical path (docs/performance.md, 2026-12-01)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.fingertip_kinematics not in FINGERTIP_KINEMATICS:
            raise ValueError(
                f"unknown fingertip_kinematics {self.fingertip_kinematics!r}; "
                f"valid: {list(FINGERTIP_KINEMATICS)}"
            )
        check_multiple("resample_period_s", self.resample_period_s, self.ctrl_dt)
        if not 0.0 <= self.target_transition_s <= self.resample_period_s:
            raise ValueError(
                f"target_transition_s must be in [0, resample_period_s = {self.resample_period_s}] s, got "
                f"{self.target_transition_s}"
            )

    @property
    def resample_steps(self) -> int:
        """Target resampling period in control steps."""
        return round(self.resample_period_s / self.ctrl_dt)


def default_config() -> ReachEnvConfig:
    """The training configuration: every actuator effect and randomisation on."""
    return ReachEnvConfig()


def neck_config() -> ReachEnvConfig:
    """``LiteReachNeck``'s training configuration: ``default_config()`` on the arms and the neck."""
    return replace(default_config(), mode="arms_neck")


def nominal_config(base: ReachEnvConfig | None = None) -> ReachEnvConfig:
    """``base`` (default: ``default_config()``) with every randomisation and noise off.

    See ``robot_config.nominal``: wire quantisation and torque saturation stay on.
    """
    return nominal(base or default_config())


class LiteReach(LiteRobotEnv):
    """Bimanual reach on the Lite upper body (see the module docstring for the exact semantics)."""

    task_name = "reach"

    def __init__(self, config: ReachEnvConfig | None = None, *, scene: SceneEdit | None = None) -> None:
        """Reach of ``config`` (default: ``default_config()``) in ``scene`` (None: the robot alone).

        The task reads the robot's joints through the env's addresses (``robot_q``, ``robot_dq``,
        ``with_robot_q``), so a scene's extra joints leave it unchanged.
        """
        cfg = config or default_config()
        super().__init__(cfg, ObservationManager.for_task("reach", cfg.mode), scene=scene)
        self._site_ids = np.array([self.mj_model.site(s).id for s in FINGERTIP_SITES])
        # The fingertips' body chains for the observation's forward kinematics (``site_kinematics``: the 15
        # bodies of the two arms, not ``mjx.kinematics``' every frame); None: ``mjx.kinematics`` runs.
        chains = cfg.fingertip_kinematics == "chains"
        self._tip_chains = plan_sites(self.mj_model, self._site_ids) if chains else None
        # The wrist joints (yaw, pitch, roll of each arm), indices into the robot's joint order.
        self._wrists = np.array([i for i, n in enumerate(self.robot.joint_names) if "wrist" in n])
        # The fingertips of the default pose, where each episode's commanded targets start (the deploy
        # side's ``TransitionCommands`` starts from the same ``Kinematics``), shape (2, 3), m.
        self._tips0 = to_device(Kinematics(cfg.mode).fingertips(np.asarray(self._default)), np.float32)

    def task_metadata(self) -> dict:
        """The command transition's duration (``bar.command_transition``), s."""
        return {"command_transition_s": float(self.config.target_transition_s)}

    @property
    def metric_keys(self) -> tuple[str, ...]:
        """``dist_left``, ``dist_right``, ``success``, ``success_end``, ``segment_end``."""
        return ("dist_left", "dist_right", "success", "success_end", "segment_end")

    def task_reset(self, model: mjx.Model, key: jax.Array) -> tuple[dict, jax.Array, jax.Array]:
        """New goals, the commanded targets at the default fingertips; start at the default pose at rest."""
        gl, gr = sample_targets(jax.random.uniform(key, (6,)), self.config.target)
        info = {
            "target_left": self._tips0[0],
            "target_right": self._tips0[1],
            "from_left": self._tips0[0],
            "from_right": self._tips0[1],
            "goal_left": gl,
            "goal_right": gr,
        }
        if self.config.target_transition_s <= 0:  # a step: the goal at once
            info["target_left"], info["target_right"] = gl, gr
        return info, self._default, jnp.zeros(self.action_size)

    def reward_terms(self) -> tuple[RewardTerm, ...]:
        """Reach's reward table (``term_table.reward_terms``) for the current config."""
        return term_table.reward_terms(self.config.reward)

    def termination_terms(self) -> tuple[TerminationTerm, ...]:
        """Reach's terminations (``term_table.TERMINATIONS``): none of its own."""
        return term_table.TERMINATIONS

    def task_step(self, tr: Transition) -> TaskStep:
        """Fingertip distances for the reward table, success, and target resampling at segment ends."""
        cfg = self.config
        data, info, finite = tr.data, tr.info, tr.finite
        tips = data.site_xpos[self._site_ids]
        d_l = jnp.linalg.norm(tips[0] - info["target_left"])
        d_r = jnp.linalg.norm(tips[1] - info["target_right"])
        signals = {
            "dist_left": d_l,
            "dist_right": d_r,
            "q_wrist": self.robot_q(data)[self._wrists],
            "q_wrist_default": self._default[self._wrists],
        }
        success = rewards.success(d_l, d_r, SUCCESS_RADIUS)
        seg_end = (tr.step % cfg.resample_steps) == 0
        new_l, new_r = sample_targets(jax.random.uniform(tr.key, (6,)), cfg.target)
        seg = seg_end.astype(jnp.float32)
        metrics = {
            "dist_left": jnp.where(finite, d_l, 0.0),
            "dist_right": jnp.where(finite, d_r, 0.0),
            "success": success,
            "success_end": success * seg,
            "segment_end": seg,
        }
        goal_l = jnp.where(seg_end, new_l, info["goal_left"])
        goal_r = jnp.where(seg_end, new_r, info["goal_right"])
        from_l = jnp.where(seg_end, info["target_left"], info["from_left"])
        from_r = jnp.where(seg_end, info["target_right"], info["from_right"])
        elapsed = (tr.step % cfg.resample_steps).astype(jnp.float32) * cfg.ctrl_dt
        task_info = {
            "target_left": transition_point(from_l, goal_l, elapsed, cfg.target_transition_s),
            "target_right": transition_point(from_r, goal_r, elapsed, cfg.target_transition_s),
            "from_left": from_l,
            "from_right": from_r,
            "goal_left": goal_l,
            "goal_right": goal_r,
        }
        return TaskStep(signals=signals, info=task_info, metrics=metrics)

    def task_obs(self, model: mjx.Model, data: mjx.Data, q_meas: jax.Array, info: dict) -> dict:
        """Fingertips by forward kinematics of the measured q, and the two targets.

        The fingertips are ``mjx.kinematics``' ``site_xpos`` rows; by default computed from their body chains
        alone (``site_kinematics.site_positions``: the same maths on the same, possibly randomised, model).
        This runs twice per training program (the step's observation and the auto-reset's) and in the
        evaluation: with every frame's kinematics it was about a fifth of the rollout's trace and over half of
        the reset's (docs/performance.md, 2026-12-01).
        """
        data_q = self.with_robot_q(data, q_meas)
        if self._tip_chains is None:
            tips = mjx.kinematics(model, data_q).site_xpos[self._site_ids]
        else:
            tips = site_positions(model, data_q.qpos, self._tip_chains)
        return {
            "fingertip_pos_left": tips[0],
            "fingertip_pos_right": tips[1],
            "target_pos_left": info["target_left"],
            "target_pos_right": info["target_right"],
        }
