"""The benches' config arguments (``bench/config_args.py``) build the config the trainer would.

``--env-overrides`` adds to the preset's own env overrides as the trainer's ``--env-overrides`` does, so a
bench that picks the Cholesky form keeps the reach gpu preset's 4 ms step (``bar_policy/tasks/reach/
preset.py``: ``env_overrides = ("sim_dt=0.004",)``); ``--set env_overrides=...`` still replaces the tuple.
A GPU call once measured at 2 ms because only ``--set`` existed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from config_args import add_config_args, config_argv, config_label, config_of

from bar_policy.training.cli import parse_config


def _parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_config_args(p)
    return p.parse_args(list(argv))


def test_env_overrides_add_to_the_presets_own():
    args = _parse("--env-overrides", "cholesky=columns")
    assert config_of(args).env_overrides == ("sim_dt=0.004", "cholesky=columns")
    assert config_label(args) == "preset gpu, env sim_dt=0.004 cholesky=columns"
    # A path the preset sets is replaced, the rest kept (the trainer's merge).
    args = _parse("--env-overrides", "sim_dt=0.002", "cholesky=scalar")
    assert config_of(args).env_overrides == ("sim_dt=0.002", "cholesky=scalar")
    # --set replaces the whole tuple, as for any field.
    assert config_of(_parse("--set", "env_overrides=cholesky=columns")).env_overrides == ("cholesky=columns",)


def test_the_bench_config_equals_the_trainers():
    """Same preset, same --env-overrides and PPO override: the bench's config is the trainer's."""
    args = _parse("--set", "ppo.num_envs=512", "--env-overrides", "cholesky=columns")
    trainer = parse_config(["--ppo.num-envs", "512", "--env-overrides", "cholesky=columns"])
    assert config_of(args).env_overrides == trainer.env_overrides
    assert config_of(args).ppo == trainer.ppo


def test_the_arguments_pass_to_a_child_unchanged():
    args = _parse("--preset", "tiny", "--set", "ppo.num_envs=16", "--env-overrides", "cholesky=columns")
    again = _parse(*config_argv(args))
    assert vars(again) == vars(args)
    assert config_label(args).startswith("preset tiny, ppo.num_envs=16, env ")


def test_a_bad_env_override_names_the_problem():
    with pytest.raises(ValueError, match=r"must look like 'dotted\.path=value'"):
        config_of(_parse("--env-overrides", "cholesky"))
