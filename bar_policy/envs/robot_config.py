"""Configuration of the Lite robot env, shared by every task: timing, action map, actuator, noise, DR.

A task's config subclasses ``RobotEnvConfig`` and adds its own fields (commands, reward, termination), so
one dataclass tree holds everything and dotted overrides keep their paths (``actuator.latency_steps``,
``obs_noise.joint_pos``, ``reward.scales.<term>``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TypeVar

from bar_policy.robot.action_filter import filter_alpha
from bar_policy.robot.constants import MODES, load_robot
from bar_policy.robot.gains import GAINS
from bar_policy.robot.mjcf import PHYSICS_DT

__all__ = [
    "GAINS",
    "PAYLOAD_AT",
    "ActuatorConfig",
    "ModelRandomizationConfig",
    "ObsNoiseConfig",
    "RobotEnvConfig",
    "check_multiple",
    "check_range",
    "nominal",
]


PAYLOAD_AT = ("fingertip", "palm", "either")
"""Valid ``ModelRandomizationConfig.payload_at``."""


def check_range(name: str, lo_hi: tuple[float, float], *, low: float = -math.inf) -> None:
    """``ValueError`` unless ``lo_hi`` is a finite ``(low, high)`` with ``low <= lo <= hi``."""
    lo, hi = lo_hi
    if not (math.isfinite(lo) and math.isfinite(hi) and low <= lo <= hi):
        raise ValueError(f"{name} must be (low, high) with {low} <= low <= high, got {lo_hi!r}")


def check_multiple(name: str, value: float, unit: float) -> None:
    """``ValueError`` unless ``value`` is a positive whole multiple of ``unit`` (both in s)."""
    ratio = value / unit
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6:
        raise ValueError(f"{name}={value} s must be a positive whole multiple of {unit} s")


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
    strength: tuple[float, float] = (1.0, 1.0)
    """Per-joint, per-episode motor strength U(low, high), dimensionless: the joint receives
    ``strength * clip(law, cap)`` (the torque and its cap scaled; the implicit Kd term likewise), as the
    deploy side's ``strength`` perturbation. (1, 1), the default, leaves the law as it is."""
    obs_latency_steps: tuple[int, int] = (0, 0)
    """Observation latency, control steps, inclusive integer range sampled per episode: the policy sees the
    measured joint state (q, dq, and what the task computes from q) of that many steps ago (the reset state
    until the episode has that many steps), as the deploy side's ``obs_delay_ticks``. (0, 0): none."""
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
        check_range("kp_scale", self.kp_scale, low=0.0)
        check_range("kd_scale", self.kd_scale, low=0.0)
        check_range("strength", self.strength, low=1e-3)
        lo, hi = self.obs_latency_steps
        if not (isinstance(lo, int) and isinstance(hi, int) and 0 <= lo <= hi <= 10):
            raise ValueError(
                f"obs_latency_steps must be integers 0 <= low <= high <= 10, got {self.obs_latency_steps}"
            )
        if not self.encoder_offset >= 0:
            raise ValueError(f"encoder_offset must be >= 0 rad, got {self.encoder_offset}")


@dataclass(frozen=True, kw_only=True)
class ObsNoiseConfig:
    """Per-step uniform observation noise U(-x, x) on the measured joint state (0 disables)."""

    joint_pos: float = 0.005
    """rad; also moves any observed forward kinematics (computed from the noisy measured q)."""
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
    damping: tuple[float, float] | None = None
    """Added passive joint damping ~ U(low, high) per robot joint, N*m*s/rad, on top of the MJCF's
    ``dof_damping`` (the deploy side's ``damping``); None (default) adds none."""
    armature_scale: tuple[float, float] | None = None
    """Per-joint multiplier on the robot joints' armature (after the ``armature`` draw), dimensionless;
    None (default) disables."""
    payload_kg: tuple[float, float] | None = None
    """Point mass on each hand ~ U(low, high), kg, drawn per hand (the deploy side's ``payload_kg``). Not
    None adds a massless payload body to each hand of the training scene (``randomize.payload_scene``),
    whose ``body_mass`` and ``body_inertia`` (a 1 cm solid sphere's) the randomiser sets; None (default)
    leaves the scene as it is."""
    nominal_share: float = 0.0
    """Share of env slots, 0..1, drawn as a nominal robot: in such a slot friction and link mass are drawn
    from the default ranges (0.05-0.35 N*m, x0.9-1.1; the same uniform draw mapped onto them), and the
    added damping, armature scale and payload are off (with a robot-parameters file: its values). 0
    (default): no such slot. Why: the wide ranges are drawn per joint independently, so a slot whose 14
    joints are all near the nominal robot (the one the ship gate's sim target runs) essentially never
    occurs (friction U(0.05, 1.35): P(all 14 below 0.35) = (0.3 / 1.3)^14 = 1e-9); docs/robust_training.md."""
    factor_share: float = 1.0
    """Probability, 0..1, that each robust factor is on, drawn independently per factor and env slot (the
    model's: friction's robust addition, link mass scale, added damping, armature scale, payload) and per
    factor and episode (the actuator's: ``strength``, ``latency_steps``, ``obs_latency_steps``,
    ``encoder_offset``). A factor that is off takes the value a nominal slot gives it: friction and link
    mass the same draw mapped onto the default ranges (0.05-0.35 N*m, x0.9-1.1), no added damping,
    armature scale 1, no payload (with a robot-parameters file: its values); the actuator's factors the
    default ``ActuatorConfig``'s draw (strength 1, no observation latency, action latency in (0, 2) steps,
    encoder offset U(-0.01, 0.01) rad). A nominal slot (``nominal_share``) stays nominal in every factor. 1
    (default): every factor on, the draws as without it, bit for bit. Why: the wide ranges drawn all at
    once make a slot where everything is hard at once common, unlike the deploy suite's rows, which perturb
    one factor at a time (plus one combined row); with share p a slot carries 5p model perturbations on
    average (docs/robust_training.md)."""
    payload_at: str = "fingertip"
    """Where the payload sits in the hand (``PAYLOAD_AT``): ``fingertip`` (the finger2 tip site), ``palm``
    (the palm collider's centre), or ``either`` (one of the two per env slot and hand, even odds)."""
    payload_ff_share: tuple[float, float] | None = None
    """Share, dimensionless, of each hand's payload gravity torque fed forward as the MIT command's
    ``tau_ff``, drawn per episode and hand ~ U(low, high): models the deploy runtime's hand-load
    compensation (``deploy.hand_load``, which reads about 0.68 of a fingertip load in the piano's count-in).
    Each command carries ``sum_b share_b J_p(b)^T (0, 0, m_b g)`` of the payload bodies at the state it is
    sent from (``envs.payload_ff``); a slot or episode without a payload (``factor_share``,
    ``nominal_share``) has payload mass 0 and so no feed-forward. Needs ``payload_kg``. None (default):
    ``tau_ff = 0``, the env as without it."""

    def __post_init__(self) -> None:
        if self.frictionloss is not None:
            check_range("frictionloss", self.frictionloss, low=0.0)
        if self.link_mass_scale is not None:
            check_range("link_mass_scale", self.link_mass_scale, low=1e-3)
        if self.damping is not None:
            check_range("damping", self.damping, low=0.0)
        if self.armature_scale is not None:
            check_range("armature_scale", self.armature_scale, low=1e-3)
        if self.payload_kg is not None:
            check_range("payload_kg", self.payload_kg, low=0.0)
        if not 0.0 <= self.nominal_share <= 1.0:
            raise ValueError(f"nominal_share must be in [0, 1], got {self.nominal_share}")
        if not 0.0 <= self.factor_share <= 1.0:
            raise ValueError(f"factor_share must be in [0, 1], got {self.factor_share}")
        if self.payload_ff_share is not None:
            check_range("payload_ff_share", self.payload_ff_share, low=0.0)
            if self.payload_kg is None:
                raise ValueError(
                    f"payload_ff_share={self.payload_ff_share!r} feeds the payload's gravity torque "
                    "forward and needs payload_kg, which is None"
                )
        if self.payload_at not in PAYLOAD_AT:
            raise ValueError(f"unknown payload_at {self.payload_at!r}; valid: {list(PAYLOAD_AT)}")


@dataclass(frozen=True, kw_only=True)
class RobotEnvConfig:
    """What every Lite task shares. Subclass it for a task; derive variants with ``dataclasses.replace``."""

    mode: str = "arms"
    """Joint set: ``arms`` (14) or ``arms_neck`` (17)."""
    ctrl_dt: float = 0.02
    """Control period, s (50 Hz)."""
    sim_dt: float = PHYSICS_DT
    """Physics timestep, s (Euler). See docs/physics.md before changing it."""
    cholesky: str = "library"
    """How the physics step factors the dense mass matrix and the Newton Hessian (``physics_step.CHOLESKY``):
    ``library`` (jax's cuSOLVER / LAPACK calls, MJX's own) or ``scalar`` / ``columns`` (written out,
    ``envs.small_spd``: XLA can record them into CUDA graphs). The same physics to rounding
    (tests/envs/test_physics_step.py); docs/performance.md, 2026-11-28."""
    episode_length_s: float = 5.0
    """Episode length, s (250 control steps); the wrappers truncate episodes there."""
    action_scale: float | tuple[float, ...] | None = 0.8
    """q_cmd = default_pose + action_scale * action, rad per unit action: one value for every joint, one
    per joint (canonical order), or None for the task's own per-joint default."""
    init_noise: float = 0.05
    """Half-width of the initial joint-position noise around the task's initial pose, rad."""
    action_filter_hz: float | None = None
    """Cutoff of the first-order low-pass between the policy's action and the command, Hz
    (``bar_policy.robot.action_filter``; the deploy runtime applies the same one, from the file's
    ``bar.action_filter``); None: no filter, the action is applied as it comes."""
    gains: str = "robot"
    """Kp/Kd of the MIT command, a profile of ``robot.gains.GAINS``: ``robot`` (the joint table: Humanoid
    Control's first-activation gains, 50 and 2 on every arm joint), ``stiff`` (Kp x 2, Kd x 1.5: 100 and 3)
    or ``actuator`` (derived from each joint's armature J as lite_description does, BeyondMimic's recipe:
    ``Kp = J w^2``, ``Kd = 2 zeta J w``, ``w = 2 pi 10 Hz``, ``zeta = 2``). The file records it
    (``bar.gains``) and the runtime checks the file's gains against it."""
    actuator: ActuatorConfig = field(default_factory=ActuatorConfig)
    """Actuator model and its per-episode randomisation."""
    obs_noise: ObsNoiseConfig = field(default_factory=ObsNoiseConfig)
    """Observation noise."""
    randomization: ModelRandomizationConfig = field(default_factory=ModelRandomizationConfig)
    """Model-level randomisation used by ``get_randomizer``."""
    evaluate_nominal: bool = False
    """The trainer's evaluations (and the best-iterate choice and early stop that read them) run the task on
    its nominal robot (``nominal(config)``: no randomisation, no noise), the robot the ship gate's sim target
    runs, instead of the training randomisation. False (default): as the task does (reach, piano: the
    training env; the tracker always evaluates nominal)."""
    joint_error_ema: bool = False
    """Add the integral-like observation term ``joint_error_ema`` (``robot.error_ema``: the moving average
    of the joint command minus the measured position, tau 0.5 s) to the task's layout, as its next version
    (``obs.robot_layout.with_error_ema``: ``lite_reach_arms`` v2). False (default): the shipped layout."""
    terminate_on_cap_fault: bool = False
    """End an episode on the deploy supervisor's saturation fault: a joint whose unclipped MIT demand, as
    the supervisor computes it (the command the runtime sends, before any action latency, at the state it
    has read: ``LiteRobotEnv._supervised_torques``), sits at its torque cap, while the torque the motor
    reports is near it too (``quality.metrics.at_cap``), for more than
    ``quality.metrics.CAP_DWELL_S`` (0.5 s) unbroken (``info["cap_dwell"]``, s per joint;
    ``envs.terminations.cap_fault``). On the robot that fault ends the run in damping; without the
    termination a training episode rides on (the tracker's fast wrist-yaw clips under two ticks of action
    delay, docs/robust_training.md). False (default): no such termination."""
    robot_params: str | None = None
    """Path of a robot-parameters file (``bar_policy.robot.params``, ``bar-bus identify --out``;
    ``bar-train --robot-params FILE``): the model is the identified robot (the file's friction, damping,
    armature and payloads; the motors its strengths) and the randomisation is centred on its values
    (``envs.randomize``, docs/sysid.md). None (default): the description's model."""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown mode {self.mode!r}; valid modes: {list(MODES)}")
        if not (self.sim_dt > 0 and self.ctrl_dt > 0):
            raise ValueError(f"ctrl_dt and sim_dt must be > 0 s, got {self.ctrl_dt}, {self.sim_dt}")
        check_multiple("ctrl_dt", self.ctrl_dt, self.sim_dt)
        check_multiple("episode_length_s", self.episode_length_s, self.ctrl_dt)
        scale = self.action_scale if isinstance(self.action_scale, tuple) else (self.action_scale,)
        n = load_robot(self.mode).num_joints
        if scale != (None,) and (len(scale) not in (1, n) or not all(s > 0 for s in scale)):
            raise ValueError(
                f"action_scale must be > 0 rad, one value or {n} (mode {self.mode!r}), got "
                f"{self.action_scale}"
            )
        if not self.init_noise >= 0:
            raise ValueError(f"init_noise must be >= 0 rad, got {self.init_noise}")
        if self.gains not in GAINS:
            raise ValueError(f"unknown gains {self.gains!r}; valid: {list(GAINS)}")
        filter_alpha(self.action_filter_hz, self.ctrl_dt)  # validates the cutoff
        if self.robot_params is not None:
            from bar_policy.robot.params import load_params

            load_params(self.robot_params, load_robot(self.mode))  # ParamsError (a ValueError): one line

    @property
    def n_substeps(self) -> int:
        """Physics steps per control step."""
        return round(self.ctrl_dt / self.sim_dt)

    @property
    def episode_length(self) -> int:
        """Episode length in control steps."""
        return round(self.episode_length_s / self.ctrl_dt)


C = TypeVar("C", bound=RobotEnvConfig)


def nominal(base: C) -> C:
    """``base`` with every randomisation and noise off (any task's config).

    Wire quantisation and torque saturation stay on (they are the nominal actuator, not randomisation).
    Use it for evaluation, the parity test and sim2sim comparisons.
    """
    return replace(
        base,
        init_noise=0.0,
        actuator=replace(
            base.actuator,
            latency_steps=(0, 0),
            kp_scale=(1.0, 1.0),
            kd_scale=(1.0, 1.0),
            encoder_offset=0.0,
            strength=(1.0, 1.0),
            obs_latency_steps=(0, 0),
        ),
        obs_noise=ObsNoiseConfig(joint_pos=0.0, joint_vel=0.0),
        randomization=ModelRandomizationConfig(armature=False, frictionloss=None, link_mass_scale=None),
    )
