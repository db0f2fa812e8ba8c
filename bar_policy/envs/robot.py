"""The Lite robot env: everything a task does not own, with the Robstride MIT law in the loop.

A task subclasses ``LiteRobotEnv``, passes its observation layout and fills the hooks of
``bar_policy.envs.task.TaskHooks`` (``task_reset``, ``task_step``, ``task_obs``, ``metric_keys``); the
robot env does the rest, identically for every task:

- **Action**: ``a`` in [-1, 1]^n (canonical joint order), clipped. ``q_cmd = clip(default_pose +
  action_scale * a, lower, upper)`` with ``default_pose`` = the layout's ``default_joint_pos`` and
  ``action_scale`` per joint (``RobotEnvConfig.action_scale``).
- **Control**: MIT command ``(q_cmd, dq_cmd = 0, Kp, Kd, tau_ff = 0)`` with Kp/Kd from the robot data
  (``env.kp``, ``env.kd``; per-episode scale when randomised), 16-bit wire quantisation, at ``ctrl_dt``
  over ``n_substeps`` physics steps (Euler). Each substep computes the motor torque from the measured q
  (true q + encoder offset) and the true dq with ``bar_policy.robot.mit.firmware_torque`` (MIT law, clip
  at the firmware cap) and writes it to ``data.qfrc_applied`` before ``mjx.step``, as
  mujoco_ros2_control's MujocoSystem does; the Kd term is integrated implicitly (``actuator.py``).
- **Latency**: the applied action is the one issued ``L`` control steps ago, ``L`` sampled per episode in
  ``ActuatorConfig.latency_steps``.
- **Observation**: ``obs_manager.compute`` of the measured q (with encoder offset and noise), dq (with
  noise), the previous action (the clipped policy output, before latency), and the task's inputs.
- **Reward**: the task's named terms, each weighted by ``config.reward.scales.<name>`` (per control step,
  not multiplied by dt) and logged as ``metrics["reward/<name>"]``; a non-finite physics state ends the
  episode (``done = 1``) and zeroes the scaled terms. The task may end episodes too (``TaskStep.terminate``).
- **Initial state**: the task's initial pose + U(-init_noise, init_noise) per joint (clipped to the
  limits) and the task's initial velocity. Domain randomisation of the model is ``randomize.py``;
  episode bookkeeping and auto-reset are the wrappers' (``wrappers.py``).

PRNG use is fixed (reach's outputs are pinned by tests/data/reach_golden.npz): ``reset`` splits its key in 8
(0 initial noise, 1 the task, 2 latency, 3 Kp scale, 4 Kd scale, 5 encoder offset, 6 the next step's key,
7 observation noise); ``step`` splits ``info["rng"]`` in 3 (next key, observation noise, the task).
"""

from __future__ import annotations

from dataclasses import fields

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from bar_policy.envs.actuator import (
    ActuatorParams,
    apply_latency,
    implicit_damping,
    make_command,
    motor_torque,
)
from bar_policy.envs.base import MjxEnv, State
from bar_policy.envs.robot_config import RobotEnvConfig
from bar_policy.envs.task import TaskHooks, Transition
from bar_policy.obs import ObservationManager
from bar_policy.robot.constants import load_robot
from bar_policy.robot.mjcf import load_model

__all__ = ["LiteRobotEnv"]


class LiteRobotEnv(TaskHooks, MjxEnv):
    """The Lite with the Robstride actuator model; tasks subclass it and fill ``TaskHooks``."""

    def __init__(
        self, config: RobotEnvConfig, obs_manager: ObservationManager, default_scale: np.ndarray | None = None
    ) -> None:
        """The robot of ``config.mode`` with the task's observation layout.

        ``default_scale`` (rad, shape (n,)) is the action scale used when ``config.action_scale`` is None.
        """
        cfg = config
        self.config = cfg
        self.robot = load_robot(cfg.mode)
        mj_model = load_model(cfg.mode)
        mj_model.opt.timestep = cfg.sim_dt
        names = tuple(mj_model.joint(i).name for i in range(mj_model.njnt))
        if names != self.robot.joint_names or mj_model.nq != mj_model.nv:
            raise ValueError(f"MJCF joints {names} differ from the canonical order {self.robot.joint_names}")
        if obs_manager.joint_names != self.robot.joint_names:
            raise ValueError(f"layout {obs_manager.schema.name} is for mode {obs_manager.schema.mode!r}")
        self._mj_model = mj_model
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
        self._kp = self.robot.kp.astype(f32)
        self._kd = self.robot.kd.astype(f32)
        self._cap = self.robot.torque_cap.astype(f32)
        self._act = ActuatorParams.from_robot(
            self.robot,
            quantize_wire=cfg.actuator.quantize_wire,
            torque_saturation=cfg.actuator.torque_saturation,
        )
        self._reward_names = tuple(f.name for f in fields(cfg.reward.scales))  # type: ignore[attr-defined]

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
        """Fresh episode: the task's pose + noise, the task's velocity, new actuator samples."""
        ks = jax.random.split(rng, 8)
        return self._reset(model, ks, self.task_reset(model, ks[1]))

    def _reset(self, model: mjx.Model, ks: jax.Array, task: tuple[dict, jax.Array, jax.Array]) -> State:
        """The reset state from the 8 keys ``ks`` and the task's ``(info, pose, velocity)``."""
        cfg = self.config
        n = self.action_size
        task_info, q_init, qvel_init = task
        noise = jax.random.uniform(ks[0], (n,), minval=-cfg.init_noise, maxval=cfg.init_noise)
        q0 = jnp.clip(q_init + noise, self._lower, self._upper)
        data = self._init_data.replace(qpos=q0, qvel=qvel_init)
        act = cfg.actuator
        lat_lo, lat_hi = act.latency_steps
        latency = jax.random.randint(ks[2], (), lat_lo, lat_hi + 1)
        kp = self._kp * jax.random.uniform(ks[3], (n,), minval=act.kp_scale[0], maxval=act.kp_scale[1])
        kd = self._kd * jax.random.uniform(ks[4], (n,), minval=act.kd_scale[0], maxval=act.kd_scale[1])
        off = jax.random.uniform(ks[5], (n,), minval=-act.encoder_offset, maxval=act.encoder_offset)
        info = {
            "rng": ks[6],
            "step": jnp.zeros((), jnp.int32),
            **task_info,
            "last_act": jnp.zeros(n),
            "act_buf": jnp.zeros((lat_hi + 1, n)),
            "latency": latency,
            "kp": kp,
            "kd": kd,
            "encoder_offset": off,
        }
        obs = self._observe(model, data, info, jnp.zeros(n), ks[7])
        metrics = {f"reward/{k}": jnp.zeros(()) for k in self._reward_names}
        metrics.update({k: jnp.zeros(()) for k in self.metric_keys})
        return State(data=data, obs=obs, reward=jnp.zeros(()), done=jnp.zeros(()), metrics=metrics, info=info)

    def step_with_model(self, model: mjx.Model, state: State, action: jax.Array) -> State:
        """One control step: latency, MIT command, ``n_substeps`` physics steps, the task, obs."""
        cfg = self.config
        info = state.info
        action = jnp.clip(action, -1.0, 1.0)
        rng, k_noise, k_task = jax.random.split(info["rng"], 3)
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

        # A non-finite state ends the episode (the wrapper resets it) and logs zeros, not NaN.
        finite = jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))
        step = info["step"] + 1
        task = self.task_step(Transition(model, data, info, action, jnp.mean(tau_sq), step, finite, k_task))
        end = jnp.logical_not(finite)
        if task.terminate is not None:
            end = jnp.logical_or(end, task.terminate)
        done = end.astype(jnp.float32)
        scales = cfg.reward.scales  # type: ignore[attr-defined]
        scaled = {k: jnp.where(finite, v * getattr(scales, k), 0.0) for k, v in task.terms.items()}
        reward = sum(scaled.values())
        new_info = {**info, "rng": rng, "step": step, **task.info, "last_act": action, "act_buf": buf}
        obs = self._observe(model, data, new_info, action, k_noise)
        metrics = {f"reward/{k}": v for k, v in scaled.items()}
        metrics.update(task.metrics)
        return State(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=new_info)

    def _observe(
        self, model: mjx.Model, data: mjx.Data, info: dict, action: jax.Array, key: jax.Array
    ) -> jax.Array:
        """Observation from the measured state: q + offset (+ noise), dq (+ noise), the task's inputs."""
        nz = self.config.obs_noise
        q = data.qpos + info["encoder_offset"]
        dq = data.qvel
        kq, kv = jax.random.split(key)
        if nz.joint_pos > 0:
            q = q + jax.random.uniform(kq, q.shape, minval=-nz.joint_pos, maxval=nz.joint_pos)
        if nz.joint_vel > 0:
            dq = dq + jax.random.uniform(kv, dq.shape, minval=-nz.joint_vel, maxval=nz.joint_vel)
        inputs = {"joint_pos": q, "joint_vel": dq, "actions": action}
        inputs.update(self.task_obs(model, data, q, info))
        return self.obs_manager.compute(inputs)
