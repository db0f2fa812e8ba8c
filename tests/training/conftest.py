"""Shared, module-compiled training runs on the stand-in env (``toy_env.ToyReach``).

Each run is done once per session and reused: the brax run feeds the improvement, artifact, export and
resume tests; the rsl-rl run feeds its own tests.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from toy_env import ToyReach

from bar_policy.training.config import apply_overrides, preset

TOY_BRAX = [
    "ppo.num_envs=128",
    "ppo.batch_size=128",
    "ppo.num_minibatches=8",
    "ppo.unroll_length=10",
    "ppo.num_updates_per_batch=2",
    "ppo.num_timesteps=512000",
    "ppo.learning_rate=1e-3",
    "ppo.entropy_cost=1e-3",
    "eval.num_evals=3",
    "eval.num_eval_envs=64",
    "final_eval_envs=128",
    "seed=0",
    "log_every_iterations=13",
]
"""Tiny brax config on the toy env: 10,240 env steps per iteration, 50 iterations, 2 evaluation periods."""

TOY_RSL = [
    "backend=rsl-rl",
    "ppo.num_envs=32",
    "ppo.batch_size=32",
    "ppo.num_minibatches=2",
    "ppo.unroll_length=8",
    "ppo.num_updates_per_batch=2",
    "ppo.num_timesteps=2560",
    "eval.num_evals=3",
    "eval.num_eval_envs=32",
    "final_eval_envs=32",
    "network.activation=elu",
    "seed=0",
]
"""Tiny rsl-rl config on the toy env: 256 env steps per iteration, 10 iterations."""


def toy_config(tmp: Path, name: str, extra: list[str]) -> object:
    return apply_overrides(preset("tiny"), [f"runs_dir={tmp}", f"run_name={name}", *extra])


@pytest.fixture(scope="session")
def toy_env() -> ToyReach:
    return ToyReach()


@pytest.fixture(scope="session")
def brax_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "brax", TOY_BRAX)
    return cfg, run(cfg, env=toy_env)


@pytest.fixture(scope="session")
def rsl_run(tmp_path_factory: pytest.TempPathFactory, toy_env: ToyReach) -> tuple:
    from bar_policy.training.run import run

    tmp = tmp_path_factory.mktemp("runs")
    cfg = toy_config(tmp, "rsl", TOY_RSL)
    return cfg, run(cfg, env=toy_env)
