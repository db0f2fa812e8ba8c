"""A cheap stand-in for LiteReach with the same interface, sizes and metadata sources (no MuJoCo).

14 first-order joints ``q += gain * (q_cmd - q)`` with ``q_cmd = default + scale * action``; each
"fingertip" is a fixed linear map of its arm's 7 joints; targets are fingertips of random reachable
poses. Observation = the real reach schema (54 entries, ``ObservationManager.for_task("reach", "arms")``).
Reward = mean over hands of ``1 - tanh(d / 0.15)`` (the coarse reach kernel), logged as two terms as the
robot env logs its table: ``reward/reach_left`` and ``reward/reach_right``, each ``0.5 * (1 - tanh(d /
0.15))`` of its hand, summing to the reward. Metrics as LiteReach: ``success``, ``success_end``,
``segment_end``, ``dist_left``, ``dist_right``.

It compiles in seconds on a CPU and PPO improves it within a few iterations, so the trainer's tests
measure the trainer, not MJX compile time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from bar_policy.envs.base import MjxEnv, State
from bar_policy.obs import ObservationManager
from bar_policy.robot import load_robot


@dataclass(frozen=True, kw_only=True)
class ToyActuator:
    latency_steps: tuple[int, int] = (0, 0)
    kp_scale: tuple[float, float] = (1.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class ToyConfig:
    mode: str = "arms"
    ctrl_dt: float = 0.02
    sim_dt: float = 0.002
    episode_length_s: float = 0.4
    segment_steps: int = 10
    gain: float = 0.3
    action_scale: float = 0.8
    actuator: ToyActuator = field(default_factory=ToyActuator)

    @property
    def episode_length(self) -> int:
        return round(self.episode_length_s / self.ctrl_dt)


class ToyReach(MjxEnv):
    def __init__(self, config: ToyConfig | None = None) -> None:
        self.config = config or ToyConfig()
        self.robot = load_robot("arms")
        self.obs_manager = ObservationManager.for_task("reach", "arms")
        self._default = np.asarray(self.obs_manager.schema.default_joint_pos, np.float32)
        self._fk = np.zeros((2, 3, 7), np.float32)
        self._fk[:, :, :3] = 0.5 * np.eye(3, dtype=np.float32)

    # properties -------------------------------------------------------------------------------------
    mj_model = None  # type: ignore[assignment]
    reward_names = ("reach_left", "reach_right")
    """The reward terms (metrics ``reward/<name>``), as ``LiteRobotEnv.reward_names``."""
    metric_keys = ("dist_left", "dist_right", "success", "success_end", "segment_end")
    """The task metrics besides the reward terms, as ``TaskHooks.metric_keys``."""

    @property
    def mjx_model(self) -> dict:
        return {"gain": jnp.float32(self.config.gain)}

    @property
    def dt(self) -> float:
        return self.config.ctrl_dt

    @property
    def n_substeps(self) -> int:
        return 10

    @property
    def episode_length(self) -> int:
        return self.config.episode_length

    @property
    def observation_size(self) -> int:
        return self.obs_manager.size

    @property
    def action_size(self) -> int:
        return 14

    @property
    def action_scale(self) -> np.ndarray:
        return np.full(14, self.config.action_scale, np.float32)

    @property
    def default_pose(self) -> np.ndarray:
        return self._default.copy()

    @property
    def kp(self) -> np.ndarray:
        return self.robot.kp.astype(np.float32)

    @property
    def kd(self) -> np.ndarray:
        return self.robot.kd.astype(np.float32)

    def quality_signals(self, state: State, action: jax.Array) -> dict:
        """The robot env's quality signals for the toy: the MIT law at the robot gains (Kd term 0)."""
        q = state.data["q"]
        q_cmd = self._default + self.config.action_scale * jnp.clip(action, -1.0, 1.0)
        a = jnp.clip(action, -1.0, 1.0)
        return {"demand": self.kp * (q_cmd - q), "q": q, "action": a, "signal": q_cmd}

    # dynamics ---------------------------------------------------------------------------------------
    def _tips(self, q: jax.Array) -> tuple[jax.Array, jax.Array]:
        d = q - self._default
        return self._fk[0] @ d[:7], self._fk[1] @ d[7:]

    def _targets(self, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        return self._tips(self._default + jax.random.uniform(key, (14,), minval=-0.5, maxval=0.5))

    def _obs(self, q: jax.Array, dq: jax.Array, a: jax.Array, info: dict) -> jax.Array:
        tl, tr = self._tips(q)
        return self.obs_manager.compute(
            {
                "joint_pos": q,
                "joint_vel": dq,
                "actions": a,
                "fingertip_pos_left": tl,
                "fingertip_pos_right": tr,
                "target_pos_left": info["target_left"],
                "target_pos_right": info["target_right"],
            }
        )

    def reset_with_model(self, model: dict, rng: jax.Array) -> State:
        k_t, k_rng = jax.random.split(rng)
        tl, tr = self._targets(k_t)
        q = jnp.asarray(self._default)
        info = {"rng": k_rng, "step": jnp.zeros((), jnp.int32), "target_left": tl, "target_right": tr}
        zeros = jnp.zeros(())
        keys = (*self.metric_keys, *(f"reward/{t}" for t in self.reward_names))
        metrics = {k: zeros for k in keys}
        obs = self._obs(q, jnp.zeros(14), jnp.zeros(14), info)
        return State(data={"q": q}, obs=obs, reward=zeros, done=zeros, metrics=metrics, info=info)

    def step_with_model(self, model: dict, state: State, action: jax.Array) -> State:
        a = jnp.clip(action, -1.0, 1.0)
        q_old = state.data["q"]
        q = q_old + model["gain"] * (self._default + self.config.action_scale * a - q_old)
        dq = (q - q_old) / self.config.ctrl_dt
        info = state.info
        pl, pr = self._tips(q)
        d_l = jnp.linalg.norm(pl - info["target_left"])
        d_r = jnp.linalg.norm(pr - info["target_right"])
        term_l, term_r = 0.5 * (1.0 - jnp.tanh(d_l / 0.15)), 0.5 * (1.0 - jnp.tanh(d_r / 0.15))
        reward = term_l + term_r
        success = ((d_l < 0.03) & (d_r < 0.03)).astype(jnp.float32)
        step = info["step"] + 1
        seg = (step % self.config.segment_steps) == 0
        rng, k_t = jax.random.split(info["rng"])
        nl, nr = self._targets(k_t)
        info = {
            **info,
            "rng": rng,
            "step": step,
            "target_left": jnp.where(seg, nl, info["target_left"]),
            "target_right": jnp.where(seg, nr, info["target_right"]),
        }
        segf = seg.astype(jnp.float32)
        metrics = {
            "dist_left": d_l,
            "dist_right": d_r,
            "success": success,
            "success_end": success * segf,
            "segment_end": segf,
            "reward/reach_left": term_l,
            "reward/reach_right": term_r,
        }
        return State(
            data={"q": q},
            obs=self._obs(q, dq, a, info),
            reward=reward,
            done=jnp.zeros(()),
            metrics=metrics,
            info=info,
        )
