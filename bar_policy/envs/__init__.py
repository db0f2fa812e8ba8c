"""MJX training envs: a small registry of name -> (env class, default config, randomizer).

Every env is a task on the Lite robot env (``robot.py``: actuator model, latency, quantisation, noise,
substeps, action map, initial state; ``robot_config.py``: its config), plugged in through the hooks of
``task.py``: ``LiteReach`` / ``LiteReachNeck`` (``reach.py``) and ``LiteTrack`` (``track.py``,
``track_config.py``). Domain randomisation (``randomize.py``) and the batched wrappers (``wrappers.py``)
are shared by every task.

Usage::

    from bar_policy import envs
    env = envs.load("LiteReach", overrides=["reward.scales.reach_fine=2.0", "episode_length_s=6.0"])
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))

For brax PPO: ``ppo.train(environment=env, wrap_env_fn=envs.wrap_for_brax_training,
randomization_fn=envs.get_randomizer("LiteReach", env.config), episode_length=env.episode_length, ...)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from bar_policy import _mjx_quiet  # noqa: F401 - first: mujoco.mjx without the Warp notice
from bar_policy.envs.base import MjxEnv, State
from bar_policy.envs.reach import LiteReach, ReachEnvConfig
from bar_policy.envs.reach import default_config as _reach_default
from bar_policy.envs.robot import LiteRobotEnv
from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.envs.track import LiteTrack
from bar_policy.envs.track_config import TrackEnvConfig
from bar_policy.envs.track_config import default_config as _track_default
from bar_policy.overrides import apply_overrides

__all__ = [
    "ALL_ENVS",
    "LiteReach",
    "LiteRobotEnv",
    "LiteTrack",
    "MjxEnv",
    "ReachEnvConfig",
    "RobotEnvConfig",
    "State",
    "TrackEnvConfig",
    "apply_overrides",
    "default_config",
    "get_randomizer",
    "load",
    "make_batched_env",
    "nominal_config",
    "wrap_for_brax_training",
]


def _randomizer(config: Any) -> Callable:
    from bar_policy.envs.randomize import make_randomizer

    return make_randomizer(config)


def _reach_neck_default() -> ReachEnvConfig:
    return dataclasses.replace(_reach_default(), mode="arms_neck")


_REGISTRY: dict[str, tuple[type[MjxEnv], Callable[[], Any], Callable[[Any], Callable]]] = {
    "LiteReach": (LiteReach, _reach_default, _randomizer),
    "LiteReachNeck": (LiteReach, _reach_neck_default, _randomizer),
    "LiteTrack": (LiteTrack, _track_default, _randomizer),
}
ALL_ENVS: tuple[str, ...] = tuple(_REGISTRY)
"""Registered env names."""


def _entry(name: str) -> tuple:
    if name not in _REGISTRY:
        raise ValueError(f"unknown env {name!r}; available envs: {list(ALL_ENVS)}")
    return _REGISTRY[name]


def default_config(name: str = "LiteReach") -> Any:
    """The default (training) config of a registered env."""
    return _entry(name)[1]()


def nominal_config(base: RobotEnvConfig | None = None) -> Any:
    """``base`` (default: LiteReach's default config) with every randomisation and noise off.

    Works for any task's config (``robot_config.nominal``); quantisation and torque saturation stay on.
    """
    return nominal(base if base is not None else _reach_default())


def load(
    name: str = "LiteReach",
    config: Any | None = None,
    overrides: Iterable[str] | Mapping[str, Any] | None = None,
) -> MjxEnv:
    """Build a registered env.

    Args:
        name: one of ``ALL_ENVS``.
        config: a full config (default: ``default_config(name)``).
        overrides: dotted-path overrides applied on top (``bar_policy.overrides.apply_overrides``: the one
            override syntax, also that of ``bar-train --env-overrides``).
    """
    cls, default, _ = _entry(name)
    cfg = config if config is not None else default()
    if overrides:
        cfg = apply_overrides(cfg, overrides)
    return cls(cfg)


def get_randomizer(name: str = "LiteReach", config: Any | None = None) -> Callable:
    """The model-level domain randomiser ``(model, rng) -> (batched_model, in_axes)`` of an env.

    ``rng`` is a batch of keys, shape (num_envs, 2) (what brax PPO passes). Pass the env's config so the
    ranges match it (default: ``default_config(name)``).
    """
    _, default, make = _entry(name)
    return make(config if config is not None else default())


def make_batched_env(*args: Any, **kwargs: Any) -> Any:
    """See ``bar_policy.envs.wrappers.make_batched_env`` (jitted batched reset/step for rsl-rl)."""
    from bar_policy.envs.wrappers import make_batched_env as _make

    return _make(*args, **kwargs)


def wrap_for_brax_training(*args: Any, **kwargs: Any) -> Any:
    """See ``bar_policy.envs.wrappers.wrap_for_brax_training`` (imported lazily)."""
    from bar_policy.envs.wrappers import wrap_for_brax_training as _wrap

    return _wrap(*args, **kwargs)
