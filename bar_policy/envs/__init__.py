"""MJX training envs: a small registry of name -> (env class, default config, randomizer).

Every env is a task on the Lite robot env (``robot.py``: actuator model, latency, quantisation, noise,
substeps, action map, initial state; ``robot_config.py``: its config), plugged in through the hooks of
``task.py``. The tasks live in their folders (``bar_policy/tasks/<task>/env.py``) and name their envs in
their ``TaskRecord``, which this registry reads from the published records (``bar_policy.task_records``):
``ALL_ENVS``, in registry order (e.g. ``LiteReach`` / ``LiteReachNeck`` of reach, ``LiteTrack`` of track).
Domain randomisation (``randomize.py``) and the batched wrappers (``wrappers.py``) are shared by every task. A
task's public MJX names (``envs.LiteReach``, ``envs.TrackEnvConfig``, ...) are found in its env modules on
first use.

Usage::

    from bar_policy import envs
    env = envs.load("LiteReach", overrides=["reward.scales.reach_fine=2.0", "episode_length_s=6.0"])
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    state = jax.jit(env.step)(state, jnp.zeros(env.action_size))

For brax PPO: ``ppo.train(environment=env, wrap_env_fn=envs.wrap_for_brax_training,
randomization_fn=envs.get_randomizer("LiteReach", env.config), episode_length=env.episode_length, ...)``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, Any

from bar_policy import _mjx_quiet  # noqa: F401 - first: mujoco.mjx without the Warp notice
from bar_policy.envs.base import MjxEnv, State
from bar_policy.envs.robot import LiteRobotEnv
from bar_policy.envs.robot_config import RobotEnvConfig, nominal
from bar_policy.overrides import apply_overrides
from bar_policy.task_records import default_env, records, resolve

if TYPE_CHECKING:
    import jax

    from bar_policy.envs.wrappers import BatchedEnv

__all__ = [
    "ALL_ENVS",
    "DEFAULT_ENV",
    "LiteRobotEnv",
    "MjxEnv",
    "RobotEnvConfig",
    "State",
    "apply_overrides",
    "default_config",
    "get_randomizer",
    "load",
    "load_for_training",
    "make_batched_env",
    "nominal_config",
    "wrap_for_brax_training",
]


def _randomizer(config: Any) -> Callable:
    from bar_policy.envs.randomize import make_randomizer

    return make_randomizer(config)


_ENTRIES = {entry.name: entry for record in records() for entry in record.envs}
ALL_ENVS: tuple[str, ...] = tuple(_ENTRIES)
"""Registered env names (the task records' ``envs``, in registry order)."""
DEFAULT_ENV: str = default_env()
"""The env the helpers below build when no name is given: the registry's first (reach's ``LiteReach``)."""


def _entry(name: str) -> tuple[type[MjxEnv], Callable[[], Any], Callable[[Any], Callable]]:
    if name not in _ENTRIES:
        raise ValueError(f"unknown env {name!r}; available envs: {list(ALL_ENVS)}")
    entry = _ENTRIES[name]
    return resolve(entry.env), resolve(entry.config), _randomizer


def default_config(name: str = DEFAULT_ENV) -> Any:
    """The default (training) config of a registered env."""
    return _entry(name)[1]()


def nominal_config(base: RobotEnvConfig | None = None) -> Any:
    """``base`` (default: ``DEFAULT_ENV``'s default config) with every randomisation and noise off.

    Works for any task's config (``robot_config.nominal``); quantisation and torque saturation stay on.
    """
    return nominal(base if base is not None else default_config())


def load(
    name: str = DEFAULT_ENV,
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
    cls, cfg, _ = _resolve(name, config, overrides)
    return cls(cfg)


def load_for_training(
    name: str = DEFAULT_ENV,
    config: Any | None = None,
    overrides: Iterable[str] | Mapping[str, Any] | None = None,
) -> tuple[MjxEnv, Callable]:
    """``(load(name, config, overrides), get_randomizer(name, env.config))``, the config resolved once.

    What a trainer takes from the registry: the env and the model-level randomiser of its own config.
    """
    cls, cfg, make = _resolve(name, config, overrides)
    return cls(cfg), make(cfg)


def _resolve(name: str, config: Any | None, overrides: Iterable[str] | Mapping[str, Any] | None) -> tuple:
    """``(env class, config with the overrides applied, randomiser factory)`` of a registered env."""
    cls, default, make = _entry(name)
    cfg = config if config is not None else default()
    return cls, apply_overrides(cfg, overrides) if overrides else cfg, make


def get_randomizer(name: str = DEFAULT_ENV, config: Any | None = None) -> Callable:
    """The model-level domain randomiser ``(model, rng) -> (batched_model, in_axes)`` of an env.

    ``rng`` is a batch of keys, shape (num_envs, 2) (what brax PPO passes). Pass the env's config so the
    ranges match it (default: ``default_config(name)``).
    """
    _, cfg, make = _resolve(name, config, None)
    return make(cfg)


def make_batched_env(
    env: MjxEnv,
    num_envs: int,
    *,
    seed: int = 0,
    randomize: bool = True,
    episode_length: int | None = None,
) -> tuple[BatchedEnv, Callable[[jax.Array], State], Callable[[State, jax.Array], State]]:
    """A batched env and its jitted ``reset(keys[B, 2])`` / ``step(state, action[B, n])``, for rsl-rl.

    ``bar_policy.envs.wrappers.make_batched_env`` (imported on first use; its docstring has the details):
    ``num_envs`` = B, ``seed`` of the model randomisation keys, ``randomize`` with the env's model-level
    randomiser, ``episode_length`` in control steps (default ``env.episode_length``).
    """
    from bar_policy.envs.wrappers import make_batched_env as _make

    return _make(env, num_envs, seed=seed, randomize=randomize, episode_length=episode_length)


def wrap_for_brax_training(
    env: MjxEnv,
    episode_length: int | None = None,
    action_repeat: int = 1,
    randomization_fn: Callable[[Any], tuple[Any, Any]] | None = None,
    *,
    auto_reset: bool = True,
) -> BatchedEnv:
    """``wrap_env_fn`` for brax's ``ppo.train``, with brax's ``envs.training.wrap`` keywords.

    ``auto_reset=False`` builds an evaluation batch without the in-step reset.
    ``bar_policy.envs.wrappers.wrap_for_brax_training``, imported on first use.
    """
    from bar_policy.envs.wrappers import wrap_for_brax_training as _wrap

    return _wrap(env, episode_length, action_repeat, randomization_fn, auto_reset=auto_reset)


def __getattr__(name: str) -> Any:
    """A registered task's public MJX name (``envs.LiteTrack``, ``envs.ReachEnvConfig``).

    Found in the first env module of the registry whose ``__all__`` lists it (imported on first use).
    """
    for entry in _ENTRIES.values():
        for ref in (entry.env, entry.config):
            module = importlib.import_module(ref.partition(":")[0])
            if name in getattr(module, "__all__", ()):
                return getattr(module, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
