"""LiteReach: each fingertip of the Lite to its own target, with the Robstride MIT law in the loop.

Semantics (fixed; the exported policy and the deploy runtime rely on them):

- **Action**: ``a`` in [-1, 1]^n (n = 14 for ``arms``, 17 for ``arms_neck``; canonical joint order). Values
  outside are clipped. ``q_cmd = clip(default_pose + action_scale * a, lower, upper)`` with
  ``default_pose`` = the obs schema's ``default_joint_pos`` (``piano_ready``) and ``action_scale`` a
  per-joint array in rad (``env.action_scale``; ``ReachEnvConfig.action_scale`` for every joint).
- **Control**: MIT command ``(q_cmd, dq_cmd = 0, Kp, Kd, tau_ff = 0)`` with Kp/Kd from the robot data
  (``env.kp``, ``env.kd``; per-episode scale when randomised). Control at ``ctrl_dt`` = 0.02 s (50 Hz) over
  ``n_substeps = ctrl_dt / sim_dt`` = 10 physics steps of 2 ms (Euler). Each substep computes the motor
  torque from the measured q (true q + encoder offset) and the true dq with
  ``bar_policy.robot.mit.firmware_torque`` (16-bit wire quantisation, MIT law, clip at the firmware cap)
  and writes it to ``data.qfrc_applied`` before ``mjx.step``, as mujoco_ros2_control's MujocoSystem does.
  The MJCF ``<motor>`` actuators are left at ctrl = 0.
- **Latency**: the applied action is the one issued ``L`` control steps ago, ``L`` sampled per episode in
  ``ActuatorConfig.latency_steps`` (inclusive; (0, 0) disables).
- **Observation**: built only by ``ObservationManager.for_task("reach", mode).compute`` (54 entries for
  arms): measured q (with encoder offset and noise), dq (with noise), the previous action (the clipped raw
  policy output of the last step, before latency), fingertip positions by forward kinematics of the
  measured q (chest frame = world frame, the chest is the fixed root), and the two targets.
- **Task**: targets from ``bar_policy.tasks.reach.sample_targets`` at reset and every
  ``resample_period_s``. Success = both fingertips within ``SUCCESS_RADIUS`` (3 cm). Rewards are the
  named terms of ``bar_policy.envs.rewards``, weighted by ``RewardScales``, per control step (not
  multiplied by dt), each logged as ``metrics["reward/<name>"]``. The reward uses the true fingertip
  positions from the last substep's kinematics (2 ms before the step's end, saving one FK pass).
- **Episodes**: the env itself ends an episode only when the physics state turns non-finite
  (``done = 1``); the wrappers truncate at ``episode_length`` = ``episode_length_s / ctrl_dt`` steps.
- **Metrics** (per step; brax sums them per episode): ``reward/<term>``, ``dist_left``, ``dist_right``
  (m), ``success`` (both hands in 3 cm now), ``segment_end`` (1 on the last step of a target segment) and
  ``success_end`` (success on that step). Success rate = sum(success_end) / sum(segment_end).
- **Initial state**: default pose + U(-init_noise, init_noise) per joint (clipped to the limits), zero
  velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy.envs import rewards
from bar_policy.envs.actuator import (
    ActuatorParams,
    apply_latency,
    implicit_damping,
    make_command,
    motor_torque,
)
from bar_policy.envs.base import MjxEnv, State
from bar_policy.obs import ObservationManager
from bar_policy.robot.constants import FINGERTIP_SITES, MODES, load_robot
from bar_policy.robot.mjcf import PHYSICS_DT, load_model
from bar_policy.tasks.reach import SUCCESS_RADIUS, ReachTargetConfig, sample_targets

__all__ = [
    "ActuatorConfig",
    "LiteReach",
    "ModelRandomizationConfig",
    "ObsNoiseConfig",
    "ReachEnvConfig",
    "RewardConfig",
    "RewardScales",
    "default_config",
    "nominal_config",
]


# ---------------------------------------------------------------------------------------------------
# Config
# ---------------------------------------------------------------------------------------------------
def _check_range(name: str, lo_hi: tuple[float, float], *, low: float = -math.inf) -> None:
    lo, hi = lo_hi
    if not (math.isfinite(lo) and math.isfinite(hi) and low <= lo <= hi):
        raise ValueError(f"{name} must be (low, high) with {low} <= low <= high, got {lo_hi!r}")


@dataclass(frozen=True, kw_only=True)
class RewardScales:
    """Weights of the reward terms (positive: reward, negative: cost). 0 drops a term's effect."""

    reach_coarse: float = 1.0
    """Weight of ``1 - tanh(d / coarse_std)`` (mean of both hands), per step."""
    reach_fine: float = 1.0
    """Weight of ``1 - tanh(d / fine_std)`` (mean of both hands), per step."""
    success: float = 0.5
    """Weight of the both-hands-within-3-cm indicator, per step."""
    action_rate: float = -0.01
    """Weight of ``sum((a_t - a_{t-1})^2)``, per step (action units)."""
    joint_limit: float = -1.0
    """Weight of rad beyond the soft joint limits (summed over joints), per step."""
    torque: float = -0.005
    """Weight of ``sum((tau / tau_cap)^2)`` averaged over substeps, per step."""
    joint_vel: float = -5e-4
    """Weight of ``sum(dq^2)`` in (rad/s)^2, per step."""


@dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """Reward shaping."""

    scales: RewardScales = field(default_factory=RewardScales)
    """Term weights."""
    coarse_std: float = 0.15
    """Length scale of the coarse distance kernel, m."""
    fine_std: float = 0.03
    """Length scale of the fine distance kernel, m (the success radius)."""
    soft_limit_fraction: float = 0.95
    """Fraction of each joint's range inside which the joint-limit cost is zero."""

    def __post_init__(self) -> None:
        if not (self.coarse_std > 0 and self.fine_std > 0):
            raise ValueError(f"kernel stds must be > 0 m, got {self.coarse_std}, {self.fine_std}")
        if not 0 < self.soft_limit_fraction <= 1:
            raise ValueError(f"soft_limit_fraction must be in (0, 1], got {self.soft_limit_fraction}")


@dataclass(frozen=True, kw_only=True)
class ActuatorConfig:
    """The Robstride actuator model and its per-episode randomisation. Ranges are sampled uniformly."""

    quantize_wire: bool = True
    """16-bit encoding of every MIT command field (per motor model's ranges)."""
    torque_saturation: bool = True
    """Clip the law's torque at the firmware cap (``RobotSpec.torque_cap``); False leaves it unclipped."""
    latency_steps: tuple[int, int] = (0, 2)
    """Action latency, control steps (20 ms each), inclusive integer range sampled per episode."""
    kp_scale: tuple[float, float] = (0.9, 1.1)
    """Per-joint, per-episode multiplier on Kp, dimensionless."""
    kd_scale: tuple[float, float] = (0.8, 1.2)
    """Per-joint, per-episode multiplier on Kd, dimensionless."""
    encoder_offset: float = 0.01
    """Half-width of the per-joint, per-episode encoder offset U(-x, x), rad (added to measured q)."""
    damping: str = "implicit"
    """How the integrator treats the law's Kd term: ``implicit`` (Kd of unsaturated joints goes into
    Euler's implicit joint damping, the applied force is unchanged; stable at 2 ms with a 6x margin) or
    ``explicit`` (torque only through qfrc_applied, exactly mujoco_ros2_control; only 3% inside the
    stability bound at 2 ms and unstable with Kd > 1.03x nominal). See docs/physics.md."""

    def __post_init__(self) -> None:
        if self.damping not in ("implicit", "explicit"):
            raise ValueError(f"damping must be 'implicit' or 'explicit', got {self.damping!r}")
        lo, hi = self.latency_steps
        if not (isinstance(lo, int) and isinstance(hi, int) and 0 <= lo <= hi <= 10):
            raise ValueError(
                f"latency_steps must be integers 0 <= low <= high <= 10, got {self.latency_steps}"
            )
        _check_range("kp_scale", self.kp_scale, low=0.0)
        _check_range("kd_scale", self.kd_scale, low=0.0)
        if not self.encoder_offset >= 0:
            raise ValueError(f"encoder_offset must be >= 0 rad, got {self.encoder_offset}")


@dataclass(frozen=True, kw_only=True)
class ObsNoiseConfig:
    """Per-step uniform observation noise U(-x, x) on the measured joint state (0 disables)."""

    joint_pos: float = 0.005
    """rad; also moves the observed fingertips (they are FK of the noisy measured q)."""
    joint_vel: float = 0.1
    """rad/s."""

    def __post_init__(self) -> None:
        if not (self.joint_pos >= 0 and self.joint_vel >= 0):
            raise ValueError(f"noise half-widths must be >= 0, got {self.joint_pos}, {self.joint_vel}")


@dataclass(frozen=True, kw_only=True)
class ModelRandomizationConfig:
    """Model-level randomisation (``bar_policy.envs.randomize.domain_randomize``), fixed per env slot."""

    armature: bool = True
    """Armature ~ U(description, identified) per joint (robstride-protocol.md section 8, up to ~7x)."""
    frictionloss: tuple[float, float] | None = (0.05, 0.35)
    """Joint Coulomb friction ~ U(low, high) per joint, N*m; None keeps the MJCF value (0.1)."""
    link_mass_scale: tuple[float, float] | None = (0.9, 1.1)
    """Per-body multiplier on mass and inertia (density scaling), dimensionless; None disables."""

    def __post_init__(self) -> None:
        if self.frictionloss is not None:
            _check_range("frictionloss", self.frictionloss, low=0.0)
        if self.link_mass_scale is not None:
            _check_range("link_mass_scale", self.link_mass_scale, low=1e-3)


@dataclass(frozen=True, kw_only=True)
class ReachEnvConfig:
    """Everything LiteReach needs. Build with ``default_config()``; derive with ``dataclasses.replace``."""

    mode: str = "arms"
    """Joint set: ``arms`` (14) or ``arms_neck`` (17)."""
    ctrl_dt: float = 0.02
    """Control period, s (50 Hz)."""
    sim_dt: float = PHYSICS_DT
    """Physics timestep, s (Euler). See docs/physics.md before changing it."""
    episode_length_s: float = 5.0
    """Episode length, s (250 control steps)."""
    resample_period_s: float = 2.5
    """Targets are resampled every this many s, s (a multiple of ctrl_dt)."""
    action_scale: float = 0.8
    """q_cmd = default_pose + action_scale * action, rad per unit action (every joint)."""
    init_noise: float = 0.05
    """Half-width of the initial joint-position noise around the default pose, rad."""
    target: ReachTargetConfig = field(default_factory=ReachTargetConfig)
    """Target workspace (chest frame)."""
    reward: RewardConfig = field(default_factory=RewardConfig)
    """Reward terms and weights."""
    actuator: ActuatorConfig = field(default_factory=ActuatorConfig)
    """Actuator model and its per-episode randomisation."""
    obs_noise: ObsNoiseConfig = field(default_factory=ObsNoiseConfig)
    """Observation noise."""
    randomization: ModelRandomizationConfig = field(default_factory=ModelRandomizationConfig)
    """Model-level randomisation used by ``get_randomizer``."""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r}; valid modes: {list(MODES)}")
        if not (self.sim_dt > 0 and self.ctrl_dt > 0):
            raise ValueError(f"ctrl_dt and sim_dt must be > 0 s, got {self.ctrl_dt}, {self.sim_dt}")
        for name, value, unit in (
            ("ctrl_dt", self.ctrl_dt, self.sim_dt),
            ("episode_length_s", self.episode_length_s, self.ctrl_dt),
            ("resample_period_s", self.resample_period_s, self.ctrl_dt),
        ):
            ratio = value / unit
            if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6:
                raise ValueError(f"{name}={value} s must be a positive whole multiple of {unit} s")
        if not self.action_scale > 0:
            raise ValueError(f"action_scale must be > 0 rad, got {self.action_scale}")
        if not self.init_noise >= 0:
            raise ValueError(f"init_noise must be >= 0 rad, got {self.init_noise}")

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step."""
        return round(self.ctrl_dt / self.sim_dt)

    @property
    def episode_length(self) -> int:
        """Episode length in control steps."""
        return round(self.episode_length_s / self.ctrl_dt)

    @property
    def resample_steps(self) -> int:
        """Target resampling period in control steps."""
        return round(self.resample_period_s / self.ctrl_dt)


def default_config() -> ReachEnvConfig:
    """The training configuration: every actuator effect and randomisation on."""
    return ReachEnvConfig()


def nominal_config(base: ReachEnvConfig | None = None) -> ReachEnvConfig:
    """``base`` (default: ``default_config()``) with every randomisation and noise off.

    Wire quantisation and torque saturation stay on (they are the nominal actuator, not randomisation).
    Use it for evaluation, the parity test and sim2sim comparisons.
    """
    from dataclasses import replace

    base = base or default_config()
    return replace(
        base,
        init_noise=0.0,
        actuator=replace(
            base.actuator, latency_steps=(0, 0), kp_scale=(1.0, 1.0), kd_scale=(1.0, 1.0), encoder_offset=0.0
        ),
        obs_noise=ObsNoiseConfig(joint_pos=0.0, joint_vel=0.0),
        randomization=ModelRandomizationConfig(armature=False, frictionloss=None, link_mass_scale=None),
    )


# ---------------------------------------------------------------------------------------------------
# Env
# ---------------------------------------------------------------------------------------------------
_METRIC_KEYS = ("dist_left", "dist_right", "success", "success_end", "segment_end")


class LiteReach(MjxEnv):
    """Bimanual reach on the Lite upper body (see the module docstring for the exact semantics)."""

    task_name = "reach"

    def __init__(self, config: ReachEnvConfig | None = None) -> None:
        cfg = config or default_config()
        self.config = cfg
        self.robot = load_robot(cfg.mode)
        mj_model = load_model(cfg.mode)
        mj_model.opt.timestep = cfg.sim_dt
        names = tuple(mj_model.joint(i).name for i in range(mj_model.njnt))
        if names != self.robot.joint_names or mj_model.nq != mj_model.nv:
            raise ValueError(f"MJCF joints {names} differ from the canonical order {self.robot.joint_names}")
        self._mj_model = mj_model
        self._mjx_model = mjx.put_model(mj_model)
        self._init_data = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        self.obs_manager = ObservationManager.for_task("reach", cfg.mode)
        self._site_ids = np.array([mj_model.site(s).id for s in FINGERTIP_SITES])

        n = self.robot.num_joints
        f32 = np.float32
        self._default = np.asarray(self.obs_manager.schema.default_joint_pos, dtype=f32)
        self._scale = np.full(n, cfg.action_scale, dtype=f32)
        self._lower = self.robot.lower.astype(f32)
        self._upper = self.robot.upper.astype(f32)
        self._kp = self.robot.kp.astype(f32)
        self._kd = self.robot.kd.astype(f32)
        self._cap = self.robot.torque_cap.astype(f32)
        self._act = ActuatorParams.from_robot(
            self.robot,
            quantize_wire=cfg.actuator.quantize_wire,
            torque_saturation=cfg.actuator.torque_saturation,
        )
        self._reward_names = tuple(f.name for f in _fields(RewardScales))

    # -- properties --------------------------------------------------------------------------------
    @property
    def mj_model(self) -> mujoco.MjModel:
        """The compiled C model (timestep = ``config.sim_dt``)."""
        return self._mj_model

    @property
    def mjx_model(self) -> mjx.Model:
        """The nominal MJX model."""
        return self._mjx_model

    @property
    def dt(self) -> float:
        """Control period, s."""
        return self.config.ctrl_dt

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step (10)."""
        return self.config.n_substeps

    @property
    def episode_length(self) -> int:
        """Episode length, control steps (what the wrappers truncate at)."""
        return self.config.episode_length

    @property
    def observation_size(self) -> int:
        """Observation length (54 for arms, 63 for arms_neck)."""
        return self.obs_manager.size

    @property
    def action_size(self) -> int:
        """Number of actions = number of joints."""
        return self.robot.num_joints

    @property
    def action_scale(self) -> np.ndarray:
        """Radians per unit action, per joint. Shape (n,), float32 (goes into the ONNX metadata)."""
        return self._scale.copy()

    @property
    def default_pose(self) -> np.ndarray:
        """q_cmd at action 0, rad (the schema's default_joint_pos). Shape (n,), float32."""
        return self._default.copy()

    @property
    def kp(self) -> np.ndarray:
        """Nominal Kp, N*m/rad. Shape (n,)."""
        return self._kp.copy()

    @property
    def kd(self) -> np.ndarray:
        """Nominal Kd, N*m*s/rad. Shape (n,)."""
        return self._kd.copy()

    @property
    def reward_names(self) -> tuple[str, ...]:
        """Reward term names (metrics keys ``reward/<name>``)."""
        return self._reward_names

    # -- pure functions ----------------------------------------------------------------------------
    def q_command(self, action: jax.Array) -> jax.Array:
        """``clip(default + action_scale * clip(action, -1, 1), lower, upper)``, rad. Shape (..., n)."""
        a = jnp.clip(action, -1.0, 1.0)
        return jnp.clip(self._default + self._scale * a, self._lower, self._upper)

    def reset_with_model(self, model: mjx.Model, rng: jax.Array) -> State:
        """Fresh episode: default pose + noise, zero velocity, new targets and actuator samples."""
        cfg = self.config
        n = self.action_size
        ks = jax.random.split(rng, 8)
        noise = jax.random.uniform(ks[0], (n,), minval=-cfg.init_noise, maxval=cfg.init_noise)
        q0 = jnp.clip(self._default + noise, self._lower, self._upper)
        data = self._init_data.replace(qpos=q0, qvel=jnp.zeros(n))
        tl, tr = sample_targets(jax.random.uniform(ks[1], (6,)), cfg.target)
        act = cfg.actuator
        lat_lo, lat_hi = act.latency_steps
        latency = jax.random.randint(ks[2], (), lat_lo, lat_hi + 1)
        kp = self._kp * jax.random.uniform(ks[3], (n,), minval=act.kp_scale[0], maxval=act.kp_scale[1])
        kd = self._kd * jax.random.uniform(ks[4], (n,), minval=act.kd_scale[0], maxval=act.kd_scale[1])
        off = jax.random.uniform(ks[5], (n,), minval=-act.encoder_offset, maxval=act.encoder_offset)
        info = {
            "rng": ks[6],
            "step": jnp.zeros((), jnp.int32),
            "target_left": tl,
            "target_right": tr,
            "last_act": jnp.zeros(n),
            "act_buf": jnp.zeros((lat_hi + 1, n)),
            "latency": latency,
            "kp": kp,
            "kd": kd,
            "encoder_offset": off,
        }
        obs = self._observe(model, data, info, jnp.zeros(n), ks[7])
        metrics = {f"reward/{k}": jnp.zeros(()) for k in self._reward_names}
        metrics.update({k: jnp.zeros(()) for k in _METRIC_KEYS})
        return State(data=data, obs=obs, reward=jnp.zeros(()), done=jnp.zeros(()), metrics=metrics, info=info)

    def step_with_model(self, model: mjx.Model, state: State, action: jax.Array) -> State:
        """One control step: latency, MIT command, ``n_substeps`` physics steps, targets, reward, obs."""
        cfg = self.config
        info = state.info
        action = jnp.clip(action, -1.0, 1.0)
        rng, k_noise, k_tgt = jax.random.split(info["rng"], 3)
        buf, applied = apply_latency(info["act_buf"], action, info["latency"])
        cmd = make_command(self.q_command(applied), info["kp"], info["kd"], self._act)
        offset = info["encoder_offset"]
        inv_cap_sq = 1.0 / np.square(self._cap)

        implicit = cfg.actuator.damping == "implicit"

        def substep(d: mjx.Data, _: None) -> tuple[mjx.Data, jax.Array]:
            tau = motor_torque(cmd, d.qpos + offset, d.qvel, self._act)
            if implicit:
                m_sub, qfrc = implicit_damping(model, cmd.kd, tau, d.qvel, self._act.tau_cap)
            else:
                m_sub, qfrc = model, tau
            d = mjx.step(m_sub, d.replace(qfrc_applied=qfrc))
            return d, jnp.sum(jnp.square(tau) * inv_cap_sq)

        data, tau_sq = jax.lax.scan(substep, state.data, None, length=self.n_substeps)

        # Reward on the true fingertips (site_xpos of the last substep's kinematics).
        tips = data.site_xpos[self._site_ids]
        d_l = jnp.linalg.norm(tips[0] - info["target_left"])
        d_r = jnp.linalg.norm(tips[1] - info["target_right"])
        rc = cfg.reward
        terms = {
            "reach_coarse": rewards.reach_kernel(d_l, d_r, rc.coarse_std),
            "reach_fine": rewards.reach_kernel(d_l, d_r, rc.fine_std),
            "success": rewards.success(d_l, d_r, SUCCESS_RADIUS),
            "action_rate": rewards.action_rate(action, info["last_act"]),
            "joint_limit": rewards.joint_limit(data.qpos, self._lower, self._upper, rc.soft_limit_fraction),
            "torque": rewards.torque(jnp.mean(tau_sq)),
            "joint_vel": rewards.joint_vel(data.qvel),
        }
        # A non-finite state ends the episode (the wrapper resets it) and logs zeros, not NaN.
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        done = jnp.logical_not(finite).astype(jnp.float32)
        scaled = {k: jnp.where(finite, v * getattr(rc.scales, k), 0.0) for k, v in terms.items()}
        reward = sum(scaled.values())
        d_l, d_r = jnp.where(finite, d_l, 0.0), jnp.where(finite, d_r, 0.0)

        # Targets: resample at the end of every segment.
        step = info["step"] + 1
        seg_end = (step % cfg.resample_steps) == 0
        new_l, new_r = sample_targets(jax.random.uniform(k_tgt, (6,)), cfg.target)
        tl = jnp.where(seg_end, new_l, info["target_left"])
        tr = jnp.where(seg_end, new_r, info["target_right"])
        new_info = {
            **info,
            "rng": rng,
            "step": step,
            "target_left": tl,
            "target_right": tr,
            "last_act": action,
            "act_buf": buf,
        }
        obs = self._observe(model, data, new_info, action, k_noise)
        seg = seg_end.astype(jnp.float32)
        metrics = {f"reward/{k}": v for k, v in scaled.items()}
        metrics.update(
            dist_left=d_l,
            dist_right=d_r,
            success=terms["success"],
            success_end=terms["success"] * seg,
            segment_end=seg,
        )
        return State(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=new_info)

    def _observe(
        self, model: mjx.Model, data: mjx.Data, info: dict, action: jax.Array, key: jax.Array
    ) -> jax.Array:
        """Observation from the measured state: q + offset (+ noise), dq (+ noise), FK of that q."""
        nz = self.config.obs_noise
        q = data.qpos + info["encoder_offset"]
        dq = data.qvel
        kq, kv = jax.random.split(key)
        if nz.joint_pos > 0:
            q = q + jax.random.uniform(kq, q.shape, minval=-nz.joint_pos, maxval=nz.joint_pos)
        if nz.joint_vel > 0:
            dq = dq + jax.random.uniform(kv, dq.shape, minval=-nz.joint_vel, maxval=nz.joint_vel)
        tips = mjx.kinematics(model, data.replace(qpos=q)).site_xpos[self._site_ids]
        return self.obs_manager.compute(
            {
                "joint_pos": q,
                "joint_vel": dq,
                "actions": action,
                "fingertip_pos_left": tips[0],
                "fingertip_pos_right": tips[1],
                "target_pos_left": info["target_left"],
                "target_pos_right": info["target_right"],
            }
        )


def _fields(cls: type) -> tuple:
    from dataclasses import fields

    return fields(cls)
