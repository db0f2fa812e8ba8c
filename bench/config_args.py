"""The training-config arguments the GPU benches share: ``--preset``, ``--env``, ``--set``,
``--env-overrides``.

``add_config_args`` declares them; ``config_argv`` passes them on to a bench's child process; ``bench_config``
builds the config from them and ``config_label`` names it in a bench's table; ``load_env`` builds the env the
way the trainer does (``training.run``: the config's ``env_overrides`` applied); ``pick`` reads a
comma-separated choice list.

``--env-overrides`` adds to the preset's own env overrides as the trainer's ``--env-overrides`` does
(``overrides.merge_overrides``): ``--env-overrides cholesky=columns`` keeps the gpu preset's
``sim_dt=0.004``. ``--set env_overrides=...`` replaces the whole tuple, as ``--set`` does for any field
(a bench that did so lost the gpu preset's 4 ms step).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any


def add_config_args(p: argparse.ArgumentParser) -> None:
    """``--preset`` (default gpu), ``--env`` (default LiteReach), ``--set`` (dotted-path config overrides)."""
    p.add_argument("--preset", default="gpu")
    p.add_argument("--env", default="LiteReach")
    p.add_argument("--set", nargs="*", default=[], help="config overrides, e.g. ppo.num_envs=8192")
    p.add_argument(
        "--env-overrides",
        nargs="*",
        default=[],
        help="env overrides added to the preset's own (the trainer's --env-overrides), e.g. cholesky=columns",
    )


def config_argv(args: argparse.Namespace) -> list[str]:
    """The arguments of :func:`add_config_args` as a child process's command line."""
    argv = ["--preset", args.preset, "--env", args.env] + (["--set", *args.set] if args.set else [])
    return argv + (["--env-overrides", *args.env_overrides] if args.env_overrides else [])


def bench_config(preset_name: str, sets: Sequence[str] = (), env_overrides: Sequence[str] = ()) -> Any:
    """The ``TrainConfig`` of ``preset_name`` with ``sets`` applied, then ``env_overrides`` merged on top of
    its env overrides (module docstring)."""
    import dataclasses

    from bar_policy.overrides import merge_overrides
    from bar_policy.training.config import apply_overrides, preset

    cfg = apply_overrides(preset(preset_name), list(sets))
    return dataclasses.replace(cfg, env_overrides=merge_overrides(cfg.env_overrides, env_overrides))


def config_of(args: argparse.Namespace, *extra_sets: str) -> Any:
    """``bench_config`` of the parsed :func:`add_config_args` arguments (``extra_sets`` before ``--set``)."""
    return bench_config(args.preset, [*extra_sets, *args.set], args.env_overrides)


def config_label(args: argparse.Namespace) -> str:
    """``preset gpu, ppo.num_envs=8192, env sim_dt=0.004 cholesky=columns``: the config a table measured."""
    cfg = bench_config(args.preset, args.set, args.env_overrides)
    env = f"env {' '.join(cfg.env_overrides)}" if cfg.env_overrides else "env defaults"
    return ", ".join([f"preset {args.preset}", *args.set, env])


def load_env(name: str, cfg: Any) -> Any:
    """``envs.load(name)`` with ``cfg.env_overrides`` applied, as the trainer builds it."""
    from bar_policy import envs

    return envs.load(name, overrides=list(cfg.env_overrides) or None)


def pick(p: argparse.ArgumentParser, text: str, valid: Sequence[str], what: str) -> list[str]:
    """The names of the comma-separated ``text``; exits through ``p.error`` naming any not in ``valid``."""
    names = [s for s in text.split(",") if s]
    bad = [s for s in names if s not in valid]
    if bad:
        p.error(f"unknown {what} {bad}; valid: {list(valid)}")
    return names
