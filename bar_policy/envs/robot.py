"""The Lite robot env: everything a task does not own, with the Robstride MIT law in the loop.

A task subclasses ``LiteRobotEnv``, passes its observation layout and fills the hooks of
``bar_policy.envs.task.TaskHooks`` (``task_reset``, ``task_step``, ``task_obs``, ``metric_keys``); the
robot env does the rest, identically for every task:

- **Action**: ``a`` in [-1, 1]^n (canonical joint order), clipped, then (``action_filter_hz``) low-passed
  by ``bar_policy.robot.action_filter`` (the deploy runtime's filter too); the applied action is the
  observation's ``actions`` and the filter's state, which a reset sets to the action of the start pose.
  ``q_cmd = clip(default_pose + action_scale * a, lower, upper)`` with ``default_pose`` = the layout's
  ``default_joint_pos`` and ``action_scale`` per joint (``RobotEnvConfig.action_scale``).
- **Control**: MIT command ``(q_cmd, dq_cmd = 0, Kp, Kd, tau_ff)`` with Kp/Kd from the robot data or
  the armature (``RobotEnvConfig.gains``; ``env.kp``, ``env.kd``; per-episode scale when randomised),
  16-bit wire quantisation, at ``ctrl_dt`` over ``n_substeps`` physics steps (Euler). Each substep
  computes the motor torque from the measured q (true q + encoder offset) and the true dq with
  ``bar_policy.robot.mit.firmware_torque`` (MIT law, clip at the firmware cap) and writes it to
  ``data.qfrc_applied`` before ``mjx.step``, as mujoco_ros2_control's MujocoSystem does; the Kd term is
  integrated implicitly (``actuator.py``).
- **Latency**: the applied action is the one issued ``L`` control steps ago, ``L`` sampled per episode in
  ``ActuatorConfig.latency_steps``; with ``ActuatorConfig.obs_latency_steps`` the observation's measured
  joint state is the one of ``L_obs`` steps ago (``info["obs_buf"]``, the reset state at first).
- **Hand-load compensation** (``randomization.payload_ff_share``, off by default: ``tau_ff = 0``): per episode
  and hand a share of the payload's gravity torque (``envs.payload_ff``) is the command's ``tau_ff``, as the
  deploy runtime's ``deploy.hand_load`` sends it; ``info["payload_ff"]`` holds the next command's, computed
  from the state each step ends in (and the reset's), so the step, ``quality_signals`` and the supervisor's
  demand read the same one.
- **Strength** (``ActuatorConfig.strength``, off by default): per episode and joint, the joint receives
  ``s * clip(law, cap)`` and the implicit Kd term is ``s * Kd`` (the deploy side's ``strength``).
- **Observation**: ``obs_manager.compute`` of the measured q (with encoder offset and noise), dq (with
  noise), the previous action (the clipped policy output, before latency), and the task's inputs. With
  ``joint_error_ema`` the layout is the task's next version and ``info["error_ema"]`` (``robot.error_ema``:
  the average of the step's command minus the measured q, 0 at reset) is its last term.
- **Robot parameters** (``config.robot_params``): the model is the file's robot (``robot.params.scene_edit``)
  and the motors its strengths (``info["strength"]``, times the strength draw when that is on).
- **Reward and termination**: the task's term table (``reward_terms``, ``termination_terms``; rows of
  ``envs.term_table``) evaluated on the step's signals (``robot_signals`` and the task's
  ``TaskStep.signals``): each reward term weighted by ``config.reward.scales.<name>`` (per control step,
  not multiplied by dt), summed in the table's order and logged as ``metrics["reward/<name>"]``. A
  non-finite physics state ends the episode (``done = 1``, the ``non_finite`` termination every task
  gets) and zeroes the scaled terms; the task's terminations end it too.
- **Initial state**: the task's initial pose + U(-init_noise, init_noise) per joint (clipped to the
  limits) and the task's initial velocity. Domain randomisation of the model is ``randomize.py``;
  episode bookkeeping and auto-reset are the wrappers' (``wrappers.py``).
- **Scene**: the robot's ``MjSpec`` plus what the task's ``scene`` adds (``bar_policy.robot.scene``,
  docs/scenes.md). Every robot quantity above is read and written at the robot joints' addresses
  (``robot_index``; ``robot_q``, ``robot_dq``, ``with_robot_q``); the scene's other joints start at
  ``qpos0`` at rest and move only by physics.

One unit: the reset and the step share one state (``info``) whose keys each optional feature adds or
leaves out, and one PRNG layout pinned by a golden file; the actuator, randomisation, physics and term
arithmetic already live in their own modules (``actuator``, ``randomize``, ``physics_step``,
``term_table``, ``robot.error_ema``), what is left is the order in which a step applies them.

PRNG use is fixed (reach's outputs are pinned by tests/data/reach_golden.npz): ``reset`` splits its key in 8
(0 initial noise, 1 the task, 2 latency, 3 Kp scale, 4 Kd scale, 5 encoder offset, 6 the next step's key,
7 observation noise); ``step`` splits ``info["rng"]`` in 3 (next key, observation noise, the task). The
optional draws (strength, the feed-forward share, observation latency) fold a constant into key 3 and key 2
and happen only when their field is not at its default, whose state then has no ``strength``,
``payload_ff_share``, ``payload_ff``, ``obs_latency`` or ``obs_buf``;
the draws of latency, encoder offset, strength and observation latency are ``randomize.episode_draws``,
whose per-factor draws (``randomization.factor_share`` below 1) fold another constant into key 5.
"""

from __future__ import annotations

from dataclasses import fields

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy._phases import MODEL_BUILD, phase
from bar_policy.envs import physics_step
from bar_policy.envs.actuator import (
    ActuatorParams,
    apply_latency,
    implicit_damping,
    make_command,
    motor_torque,
    robot_force,
)
from bar_policy.envs.base import MjxEnv, State
from bar_policy.envs.payload_ff import draw_share, payload_feed_forward
from bar_policy.envs.randomize import episode_draws, latency_buffers, payload_body_ids, payload_scene
from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.envs.task import TaskHooks, Transition
from bar_policy.envs.term_table import TerminationTerm, check_names, reward_values, terminated, weighted_sum
from bar_policy.envs.terminations import cap_fault, non_finite
from bar_policy.obs import ObservationManager
from bar_policy.obs.action_prior import Prior
from bar_policy.obs.robot_layout import with_error_ema
from bar_policy.quality.metrics import at_cap, cap_dwell_step
from bar_policy.robot.action_filter import filter_alpha, lowpass_step, pose_action
from bar_policy.robot.constants import load_robot
from bar_policy.robot.error_ema import error_ema_alpha, error_ema_step
from bar_policy.robot.gains import profile_gains
from bar_policy.robot.index import RobotIndex
from bar_policy.robot.mit import MitCommand, mit_torque
from bar_policy.robot.params import HANDS, RobotParams, load_params, motor_strength
from bar_policy.robot.params import scene_edit as params_scene_edit
from bar_policy.robot.scene import SceneEdit, load_model

__all__ = ["CAP_FAULT", "NEAR_CAP_FRACTION", "NON_FINITE", "LiteRobotEnv"]

NEAR_CAP_FRACTION = 0.8
"""Share of a joint's torque cap above which its unclipped MIT demand counts towards ``Transition.near_cap``
(the tasks' torque-near-cap cost): the last 20 % before saturation and what a saturated joint asks beyond
its cap, up to 1 per joint (1.8 caps), so a random early policy's cost stays bounded."""

NON_FINITE = TerminationTerm("non_finite", non_finite, ("finite",))
"""The robot's termination, first of every task's: the physics state (the whole scene's) is not finite."""

CAP_FAULT = TerminationTerm("cap_fault", cap_fault, ("cap_dwell",))
"""The robot's second termination (``terminate_on_cap_fault``): the deploy supervisor's saturation fault."""


class LiteRobotEnv(TaskHooks, MjxEnv):
    """The Lite with the Robstride actuator model; tasks subclass it and fill ``TaskHooks``."""

    def __init__(
        self,
        config: RobotEnvConfig,
        obs_manager: ObservationManager,
        default_scale: np.ndarray | None = None,
        *,
        scene: SceneEdit | None = None,
    ) -> None:
        """The robot of ``config.mode`` with the task's observation layout, in the task's scene.

        ``default_scale`` (rad, shape (n,)) is the action scale used when ``config.action_scale`` is None.
        ``scene`` adds the task's bodies, joints, sites and sensors to the robot's ``MjSpec``
        (``bar_policy.robot.scene``; None: the robot alone). The robot's joints are addressed by name
        (``robot_index``), so the scene may hold other joints anywhere; they start each episode at the
        scene's ``qpos0`` at rest and get no actuator force.
        """
        cfg = config
        self.config = cfg
        self.robot = load_robot(cfg.mode)
        self.robot_params: RobotParams | None = None
        """The robot-parameters file the model is built from (``config.robot_params``), or None."""
        with_payload = set()
        if cfg.robot_params is not None:
            self.robot_params = load_params(cfg.robot_params, self.robot)
            scene = params_scene_edit(self.robot_params, scene)  # the identified joints and payloads
            with_payload = {HANDS[h] for h, p in self.robot_params.payload.items() if p.mass_kg.value > 0}
        if cfg.randomization.payload_kg is not None:
            # Massless payload bodies, given their mass by the randomiser; a hand the file gives a payload
            # has its body already (the randomiser centres its draw on that mass).
            scene = payload_scene(scene, skip=tuple(with_payload))
        with phase(MODEL_BUILD):
            mj_model = load_model(cfg.mode, scene)
        mj_model.opt.timestep = cfg.sim_dt
        self._index = RobotIndex.from_model(mj_model, self.robot.joint_names)
        # Static dof addresses for scattering the robot's forces; None: the scene is the robot alone, whose
        # arrays are used as they are (no gather or scatter, bit-identical to the robot-only env).
        self._dof = None if self._index.robot_only else self._index.dof
        # The payload bodies whose gravity torque the command feeds forward (None: tau_ff = 0).
        ff_share = cfg.randomization.payload_ff_share
        self._payload_ids = None if ff_share is None else payload_body_ids(mj_model, "payload_ff_share")
        if cfg.joint_error_ema:  # the task's layout with the integral-like term, the next version
            obs_manager = ObservationManager(with_error_ema(obs_manager.schema))
        self._ema_alpha = error_ema_alpha(cfg.ctrl_dt) if cfg.joint_error_ema else 0.0
        if obs_manager.joint_names != self.robot.joint_names:
            raise ValueError(f"layout {obs_manager.schema.name} is for mode {obs_manager.schema.mode!r}")
        self._mj_model = mj_model
        self._step_plan = physics_step.plan(mj_model, cfg.cholesky)  # mjx.step, exact speed-ups
        with phase(MODEL_BUILD):
            self._mjx_model = mjx.put_model(mj_model)
            self._init_data = mjx.put_data(mj_model, mujoco.MjData(mj_model))
        self.obs_manager = obs_manager

        n = self.robot.num_joints
        f32 = np.float32
        self._default = np.asarray(obs_manager.schema.default_joint_pos, dtype=f32)
        scale = default_scale if cfg.action_scale is None else cfg.action_scale
        if scale is None:
            raise ValueError("action_scale is None and the task gives no default per-joint scale")
        self._scale = np.array(np.broadcast_to(np.asarray(scale, dtype=f32), (n,)))
        self._lower = self.robot.lower.astype(f32)
        self._upper = self.robot.upper.astype(f32)
        kp, kd = profile_gains(self.robot, cfg.gains)
        self._kp = np.asarray(kp, dtype=f32)
        self._kd = np.asarray(kd, dtype=f32)
        self._filter_alpha = filter_alpha(cfg.action_filter_hz, cfg.ctrl_dt)
        self._cap = self.robot.torque_cap.astype(f32)
        # Per-joint strength the draws multiply: the file's (identified), else 1.
        self._strength = (
            np.ones(n, f32)
            if self.robot_params is None
            else motor_strength(self.robot_params, self.robot).astype(f32)
        )
        self._act = ActuatorParams.from_robot(
            self.robot,
            quantize_wire=cfg.actuator.quantize_wire,
            torque_saturation=cfg.actuator.torque_saturation,
        )
        self._reward_names = tuple(f.name for f in fields(cfg.reward.scales))  # type: ignore[attr-defined]
        check_names(self.reward_terms(), self._reward_names, type(self).__name__)

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
    def robot_index(self) -> RobotIndex:
        """Addresses of the robot's joints in the scene (qpos, dof, actuator), canonical order."""
        return self._index

    # -- the robot's state in the scene ------------------------------------------------------------
    def robot_q(self, data: mjx.Data) -> jax.Array:
        """The robot's true joint positions from the scene's state, rad. Shape (n,)."""
        return self._index.q(data.qpos)

    def robot_dq(self, data: mjx.Data) -> jax.Array:
        """The robot's true joint velocities from the scene's state, rad/s. Shape (n,)."""
        return self._index.dq(data.qvel)

    def with_robot_q(self, data: mjx.Data, q: jax.Array) -> mjx.Data:
        """``data`` with the robot's joints at ``q`` (rad, shape (n,)); the scene's other joints unchanged.

        Measured-pose FK: ``site_kinematics.site_positions`` of its qpos (a few sites) or ``mjx.kinematics``.
        """
        if self._dof is None:
            return data.replace(qpos=q)
        return data.replace(qpos=data.qpos.at[self._index.qpos].set(q))

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
        """Observation length."""
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
        """q_cmd at action 0, rad (the layout's default_joint_pos). Shape (n,), float32."""
        return self._default.copy()

    @property
    def action_filter_hz(self) -> float | None:
        """Cutoff of the action low-pass, Hz (None: no filter); goes into the ONNX metadata."""
        return self.config.action_filter_hz

    @property
    def kp(self) -> np.ndarray:
        """Nominal Kp, N*m/rad (``config.gains``). Shape (n,)."""
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
    def robot_signals(self, tr: Transition) -> dict[str, jax.Array]:
        """The robot's signals of a step, which every task's term table may read (unbatched).

        ``action``, ``last_action``, ``last_last_action``: the applied action of this step and of the two
        before, (n,); ``q`` (rad), ``dq`` (rad/s): the true joint state after the step, (n,); ``q_lower``,
        ``q_upper``: the joint limits, rad, (n,); ``tau_sq`` and ``near_cap``: the substep means of
        ``Transition``; ``finite``: the physics state is finite (boolean scalar).
        """
        return {
            "action": tr.action,
            "last_action": tr.info["last_act"],
            "last_last_action": tr.info["act_prev"],
            "q": self.robot_q(tr.data),
            "dq": self.robot_dq(tr.data),
            "q_lower": self._lower,
            "q_upper": self._upper,
            "tau_sq": tr.tau_sq,
            "near_cap": tr.near_cap,
            "finite": tr.finite,
        }

    def q_command(self, action: jax.Array) -> jax.Array:
        """``clip(default + action_scale * clip(action, -1, 1), lower, upper)``, rad. Shape (..., n)."""
        a = jnp.clip(action, -1.0, 1.0)
        return jnp.clip(self._default + self._scale * a, self._lower, self._upper)

    def evaluation_env(self) -> LiteRobotEnv:
        """The env the trainer evaluates on: held-out data where the task has it (default: this env).

        With ``config.evaluate_nominal``: the same task on ``nominal(config)`` (a task constructed from its
        config alone; the trainer evaluates a distinct env without model randomisation).
        """
        if self.config.evaluate_nominal:
            return type(self)(nominal(self.config))  # type: ignore[call-arg]
        return self

    def initial_action(self, q_start: jax.Array) -> jax.Array:
        """The previous action of a new episode, shape (n,).

        0, or with the action filter on, the action of the pose the episode starts from
        (``robot.action_filter.pose_action``; the deploy runtime does the same after its HOLD ramp), so the
        filter's first command continues from that pose.
        """
        if self.config.action_filter_hz is None:
            return jnp.zeros(self.action_size)
        return pose_action(q_start, self._default, self._scale)

    def filtered_action(self, last_action: jax.Array, action: jax.Array) -> jax.Array:
        """The action applied this step: clipped to [-1, 1], then low-passed when the filter is on."""
        action = jnp.clip(action, -1.0, 1.0)
        if self.config.action_filter_hz is None:
            return action
        return lowpass_step(last_action, action, self._filter_alpha)

    def _command(self, info: dict, action: jax.Array) -> tuple[jax.Array, jax.Array, MitCommand]:
        """``(applied action, new latency buffer, decoded MIT command)`` of ``action`` in state ``info``.

        The command's ``tau_ff`` is ``info["payload_ff"]`` (the hand-load compensation), else 0.
        """
        action = self.filtered_action(info["last_act"], action)
        buf, delayed = apply_latency(info["act_buf"], action, info["latency"])
        cmd = make_command(self.q_command(delayed), info["kp"], info["kd"], self._act, info.get("payload_ff"))
        return action, buf, cmd

    def _payload_ff(self, model: mjx.Model, data: mjx.Data, share: jax.Array) -> jax.Array:
        """The hand-load feed-forward of a command sent from ``data``, N*m, (n,) (``envs.payload_ff``)."""
        return payload_feed_forward(model, data, self._payload_ids, share, self._dof)

    def quality_signals(self, state: State, action: jax.Array) -> dict[str, jax.Array]:
        """What the safety and smoothness metrics (``bar_policy.quality``) see at this tick, unbatched.

        A pure function of the state and the policy's action: the MJX evaluation during training
        (``training.eval_quality``) and the rsl-rl adapter vmap it over their slots. Returns ``demand``
        (the unclipped MIT torque of the command this step applies, at the measured state: the supervisor's
        saturation test on the robot, N*m), ``q`` (true positions, rad), ``action`` (the applied action)
        and ``signal`` (the chatter signal: ``q_cmd - q_ref`` when the task has a reference
        (``task_reference``), else ``q_cmd``, rad), each shape (n,).
        """
        info, data = state.info, state.data
        applied, _, cmd = self._command(info, action)
        q_cmd = self.q_command(applied)
        ref = self.task_reference(info)
        q, dq = self.robot_q(data), self.robot_dq(data)
        return {
            "demand": mit_torque(cmd, q + info["encoder_offset"], dq),
            "q": q,
            "action": applied,
            "signal": q_cmd if ref is None else q_cmd - ref,
        }

    def action_prior(self, lead_steps: int, error_gain: float = 0.0) -> Prior:
        """The task's action prior (``obs.action_prior``), ``lead_steps`` control steps ahead.

        ``error_gain``: the gain of its integral term on ``joint_error_ema`` (``network.prior_error_gain``;
        0: none), for a task whose prior has one.

        Raises:
            ValueError: the task has none (this default: reach has no reference to follow).
        """
        raise ValueError(
            f"{type(self).__name__} has no action prior (it has no reference to follow); valid "
            "network.action_prior values for it: none"
        )

    def task_reference(self, info: dict) -> jax.Array | None:
        """The joint positions the command of this step targets, rad (n,); None for a task without one."""
        return None

    def reset_with_model(self, model: mjx.Model, rng: jax.Array, start_bin: jax.Array | None = None) -> State:
        """Fresh episode: the task's pose + noise, the task's velocity, new actuator samples.

        ``start_bin``: the adaptive sampler's start bin (``task_reset_in_bin``; tasks with ``sampler_bins``).
        """
        ks = jax.random.split(rng, 8)
        if start_bin is None:
            return self._reset(model, ks, self.task_reset(model, ks[1]))
        return self._reset(model, ks, self.task_reset_in_bin(ks[1], start_bin))  # type: ignore[attr-defined]

    @property
    def sampler_bins(self) -> int:
        """Start bins of the task's adaptive start sampler; 0: none (starts are the task's own)."""
        return 0

    def _reset(self, model: mjx.Model, ks: jax.Array, task: tuple[dict, jax.Array, jax.Array]) -> State:
        """The reset state from the 8 keys ``ks`` and the task's ``(info, pose, velocity)``."""
        cfg = self.config
        n = self.action_size
        task_info, q_init, qvel_init = task
        noise = jax.random.uniform(ks[0], (n,), minval=-cfg.init_noise, maxval=cfg.init_noise)
        q0 = jnp.clip(q_init + noise, self._lower, self._upper)
        if self._dof is None:
            data = self._init_data.replace(qpos=q0, qvel=qvel_init)
        else:
            init = self._init_data
            qpos = init.qpos.at[self._index.qpos].set(q0)
            data = init.replace(qpos=qpos, qvel=init.qvel.at[self._dof].set(qvel_init))
        act = cfg.actuator
        share = cfg.randomization.factor_share
        kp = self._kp * jax.random.uniform(ks[3], (n,), minval=act.kp_scale[0], maxval=act.kp_scale[1])
        kd = self._kd * jax.random.uniform(ks[4], (n,), minval=act.kd_scale[0], maxval=act.kd_scale[1])
        drawn = episode_draws(act, share, ks, n, None if self.robot_params is None else self._strength)
        latency, off = drawn.pop("latency"), drawn.pop("encoder_offset")
        lat_hi, obs_hi = latency_buffers(act, share)
        a_init = self.initial_action(q_init)
        optional = drawn  # strength, obs_latency: when drawn (or the file's strengths)
        if "obs_latency" in optional:
            optional["obs_buf"] = jnp.broadcast_to(self._true_state(data), (obs_hi + 1, 2, n))
        if cfg.joint_error_ema:
            optional["error_ema"] = jnp.zeros(n)  # z = 0 when a policy starts (robot.error_ema)
        if cfg.terminate_on_cap_fault:
            optional["cap_dwell"] = jnp.zeros(n)  # unbroken time at the cap, s per joint
        if self._payload_ids is not None:  # the hand-load compensation: a share per hand, the first tau_ff
            ff_share = draw_share(ks[3], cfg.randomization.payload_ff_share)
            optional["payload_ff_share"] = ff_share
            optional["payload_ff"] = self._payload_ff(model, data, ff_share)
        info = {
            "rng": ks[6],
            "step": jnp.zeros((), jnp.int32),
            **task_info,
            "last_act": a_init,
            "act_prev": a_init,  # a_{t-2} of the first step (``action_accel``): the filter's start state
            "act_buf": jnp.zeros((lat_hi + 1, n)),
            "latency": latency,
            "kp": kp,
            "kd": kd,
            "encoder_offset": off,
            **optional,
        }
        obs = self._observe(model, data, info, info["last_act"], ks[7])
        metrics = {f"reward/{k}": jnp.zeros(()) for k in self._reward_names}
        metrics.update({k: jnp.zeros(()) for k in self.metric_keys})
        return State(data=data, obs=obs, reward=jnp.zeros(()), done=jnp.zeros(()), metrics=metrics, info=info)

    def step_with_model(self, model: mjx.Model, state: State, action: jax.Array) -> State:
        """One control step: latency, MIT command, ``n_substeps`` physics steps, the task, obs."""
        cfg = self.config
        info = state.info
        rng, k_noise, k_task = jax.random.split(info["rng"], 3)
        action, buf, cmd = self._command(info, action)
        offset = info["encoder_offset"]
        strength = info.get("strength")
        dwell = None
        if "cap_dwell" in info:
            demand, reported = self._supervised_torques(state.data, info, action, cmd)
            hit = at_cap(demand, self._cap, reported=reported)
            dwell = cap_dwell_step(info["cap_dwell"], hit, cfg.ctrl_dt)
        tau_cap = self._act.tau_cap if strength is None else strength * self._act.tau_cap
        inv_cap = 1.0 / self._cap
        inv_cap_sq = 1.0 / np.square(self._cap)
        implicit = cfg.actuator.damping == "implicit"

        def substep(d: mjx.Data, _: None) -> tuple[mjx.Data, tuple[jax.Array, jax.Array]]:
            q, dq = self.robot_q(d), self.robot_dq(d)
            tau = motor_torque(cmd, q + offset, dq, self._act, strength)
            demand = jnp.abs(mit_torque(cmd, q + offset, dq)) * inv_cap
            if implicit:
                kd = cmd.kd if strength is None else strength * cmd.kd
                m_sub, qfrc = implicit_damping(model, kd, tau, dq, tau_cap, self._dof)
            else:
                m_sub, qfrc = model, robot_force(tau, self._dof, model.nv)
            d = physics_step.step(m_sub, d.replace(qfrc_applied=qfrc), self._step_plan)
            near_cap = jnp.sum(jnp.clip(demand - NEAR_CAP_FRACTION, 0.0, 1.0))
            return d, (jnp.sum(jnp.square(tau) * inv_cap_sq), near_cap)

        data, (tau_sq, near_cap) = jax.lax.scan(substep, state.data, None, length=self.n_substeps)

        # A non-finite state (of the whole scene) ends the episode (the wrapper resets it) and logs zeros.
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        step = info["step"] + 1
        tr = Transition(model, data, info, action, jnp.mean(tau_sq), step, finite, k_task, jnp.mean(near_cap))
        task = self.task_step(tr)
        signals = self.robot_signals(tr)
        if clash := sorted(signals.keys() & task.signals.keys()):
            raise ValueError(
                f"{type(self).__name__}'s task signals {clash} shadow the robot's {sorted(signals)}"
            )
        signals.update(task.signals)
        table = self.reward_terms()
        reward, scaled = weighted_sum(table, reward_values(table, signals), finite)
        robot_ends = (NON_FINITE,)
        if dwell is not None:
            robot_ends, signals["cap_dwell"] = (NON_FINITE, CAP_FAULT), dwell
        end, _ = terminated((*robot_ends, *self.termination_terms()), signals)
        done = end.astype(jnp.float32)
        new_info = {
            **info,
            "rng": rng,
            "step": step,
            **task.info,
            "act_prev": info["last_act"],
            "last_act": action,
            "act_buf": buf,
        }
        if dwell is not None:
            new_info["cap_dwell"] = dwell
        if "payload_ff" in info:  # the next command's, from the state it will be sent from
            new_info["payload_ff"] = self._payload_ff(model, data, info["payload_ff_share"])
        if "obs_buf" in info:
            newest = self._true_state(data)[None]
            new_info["obs_buf"] = jnp.concatenate([newest, info["obs_buf"][:-1]], axis=0)
        measured = self._measured(data, new_info, k_noise)
        if "error_ema" in info:  # the command this step's action issued against the q the policy reads
            new_info["error_ema"] = error_ema_step(
                info["error_ema"], self.q_command(action), measured[0], self._ema_alpha
            )
        obs = self._observe(model, data, new_info, action, k_noise, measured)
        metrics = {f"reward/{k}": v for k, v in scaled.items()}
        metrics.update(task.metrics)
        return State(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=new_info)

    def _supervised_torques(
        self, data: mjx.Data, info: dict, sent: jax.Array, cmd: MitCommand
    ) -> tuple[jax.Array, jax.Array]:
        """What the deploy supervisor checks against the cap this step: ``(demand, reported)``, N*m, (n,).

        Both at the state it has just read (``_read_state``: the observation's, without its noise), read
        once. ``demand``, as ``deploy.safety.Supervisor.check_torque`` computes it: the unclipped MIT torque
        of the command the runtime sends (``sent``, the filtered action before any action latency, at the
        file's nominal Kp and Kd, with the hand-load feed-forward ``info["payload_ff"]`` when that is on: the
        runtime checks the command with its ``tau_ff``). ``reported``: the torque the motors report, the
        firmware's MIT torque of the command it applies (``cmd``, after any action latency, at the episode's
        gains) clipped to the cap, before ``strength`` (a motor's reading is its current times its nominal
        torque constant). With latency the applied command is older and nearer the state: a policy that
        leads a delayed arm asks past the cap while its motors report a fraction of it. With observation
        latency the robot's reading is of an older tick; ``reported`` uses the current applied command at
        that state.
        """
        q, dq = self._read_state(data, info)
        zero = jnp.zeros_like(q)
        ff = info.get("payload_ff", zero)
        asked = MitCommand(q=self.q_command(sent), dq=zero, kp=self._kp, kd=self._kd, tau_ff=ff)
        return mit_torque(asked, q, dq), jnp.clip(mit_torque(cmd, q, dq), -self._cap, self._cap)

    def _true_state(self, data: mjx.Data) -> jax.Array:
        """The robot's true ``(q, dq)`` stacked, shape (2, n) (rad, rad/s): an ``obs_buf`` entry."""
        return jnp.stack([self.robot_q(data), self.robot_dq(data)])

    def _read_state(self, data: mjx.Data, info: dict) -> tuple[jax.Array, jax.Array]:
        """The ``(q, dq)`` a reading returns before noise, rad and rad/s, (n,) each.

        q + the encoder offset and dq, of ``obs_latency`` steps ago when that latency is on (the true state
        ``info["obs_buf"]`` holds): what the policy's observation and the supervisor both read.
        """
        if "obs_buf" in info:
            q, dq = info["obs_buf"][info["obs_latency"]]
            return q + info["encoder_offset"], dq
        return self.robot_q(data) + info["encoder_offset"], self.robot_dq(data)

    def _measured(self, data: mjx.Data, info: dict, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The measured ``(q, dq)`` the observation reads, rad and rad/s, (n,) each.

        q + offset (+ noise) and dq (+ noise), of ``obs_latency`` steps ago when that latency is on.
        """
        nz = self.config.obs_noise
        q, dq = self._read_state(data, info)
        kq, kv = jax.random.split(key)
        if nz.joint_pos > 0:
            q = q + jax.random.uniform(kq, q.shape, minval=-nz.joint_pos, maxval=nz.joint_pos)
        if nz.joint_vel > 0:
            dq = dq + jax.random.uniform(kv, dq.shape, minval=-nz.joint_vel, maxval=nz.joint_vel)
        return q, dq

    def _observe(
        self,
        model: mjx.Model,
        data: mjx.Data,
        info: dict,
        action: jax.Array,
        key: jax.Array,
        measured: tuple[jax.Array, jax.Array] | None = None,
    ) -> jax.Array:
        """Observation from the measured state, the last action and the task's inputs.

        ``measured``: the ``(q, dq)`` of ``_measured`` (None: drawn here with ``key``); with
        ``joint_error_ema`` on, the term is ``info["error_ema"]`` (the step advances it first).
        """
        q, dq = self._measured(data, info, key) if measured is None else measured
        inputs = {"joint_pos": q, "joint_vel": dq, "actions": action}
        if "error_ema" in info:
            inputs["joint_error_ema"] = info["error_ema"]
        inputs.update(self.task_obs(model, data, q, info))
        return self.obs_manager.compute(inputs)
