"""The training-config arguments the GPU benches share: ``--preset``, ``--env``, ``--set``.

``add_config_args`` declares them; ``config_argv`` passes them on to a bench's child process; ``load_env``
builds the env the way the trainer does (``training.run``: the config's ``env_overrides`` applied, so
``--set env_overrides=sim_dt=0.004`` reaches the env); ``pick`` reads a comma-separated choice list.
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


def config_argv(args: argparse.Namespace) -> list[str]:
    """The arguments of :func:`add_config_args` as a child process's command line."""
    return ["--preset", args.preset, "--env", args.env] + (["--set", *args.set] if args.set else [])


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
