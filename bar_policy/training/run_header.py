"""The run header: the provenance line, the run line, and every setting that differs from its default.

``header_lines`` is what a run prints first (``training.run_dir.open_run``). The settings lines follow the
run line: the training config against ``TrainConfig()``'s defaults
(the preset's changes included, so a reader sees what ``--preset tiny`` set) and the env config against the
env's default config (the preset's and the command line's env items), as ``path=value`` items of the one
override syntax (``bar_policy.overrides``): a line can be pasted back as ``--env-overrides``.
"""

from __future__ import annotations

import dataclasses
import textwrap
from pathlib import Path
from typing import Any

from bar_policy.overrides import changed_overrides
from bar_policy.training.config import TrainConfig
from bar_policy.training.progress import format_steps

__all__ = ["header_lines", "setting_lines"]

WIDTH = 110
"""Wrap width of the lines, characters."""


def header_lines(cfg: TrainConfig, env: Any, record: dict[str, Any], run_dir: Path) -> list[str]:
    """The provenance line, the run line (directory, env sizes, backend, devices, steps), the settings lines.

    ``record``: the run's record (``run_dir.open_run``: its ``provenance`` and ``device``); ``env``: the env
    trained on (a registered env's settings are compared with its default config, a stand-in's are not).
    """
    import jax

    from bar_policy import envs
    from bar_policy.provenance import describe

    registered = cfg.env_name in envs.ALL_ENVS
    settings = setting_lines(
        cfg, getattr(env, "config", None), envs.default_config(cfg.env_name) if registered else None
    )
    run_line = (
        f"run {run_dir} | {cfg.env_name} ({env.observation_size} obs, {env.action_size} actions, "
        f"dt {env.dt} s) | backend {cfg.backend} | {record['device']['device_kind']} x "
        f"{jax.device_count()} | {format_steps(cfg.ppo.num_timesteps)} steps, {cfg.ppo.num_envs} envs"
    )
    return [describe(record["provenance"])[0], run_line, *settings]


def setting_lines(cfg: TrainConfig, env_config: Any = None, env_default: Any = None) -> list[str]:
    """``["settings: preset=tiny ppo.num_envs=16 ...", "env settings (LiteReach): sim_dt=0.004 ..."]``.

    Args:
        cfg: the run's config; its fields that differ from ``TrainConfig()``'s (``env_overrides`` aside:
            their effect is the env line).
        env_config: the env's resolved config (a dataclass), or None for none (a stand-in env).
        env_default: the env's default config, the same type (None: no env line).
    """
    train = [o for o in changed_overrides(cfg, TrainConfig()) if not o.startswith("env_overrides=")]
    lines = _wrapped("settings (not the defaults): ", train)
    if dataclasses.is_dataclass(env_config) and type(env_config) is type(env_default):
        env = changed_overrides(env_config, env_default)
        lines += _wrapped(f"env settings ({cfg.env_name}, not its defaults): ", env)
    return lines


def _wrapped(head: str, items: list[str] | tuple[str, ...]) -> list[str]:
    text = head + (" ".join(items) if items else "none")
    return textwrap.wrap(text, WIDTH, subsequent_indent="  ", break_long_words=False, break_on_hyphens=False)
