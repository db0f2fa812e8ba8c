"""Tiny training configs on the stand-in env, importable by a name no other test folder uses.

(``from conftest import ...`` resolved to whichever test folder's conftest was imported first.)
"""

from __future__ import annotations

from pathlib import Path

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
    "ppo.batch_size=16",
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
"""Tiny rsl-rl config on the toy env: 256 env steps per iteration (16 x 2 segments of 8 steps = 8 steps per
env), 10 iterations."""


def toy_config(tmp: Path, name: str, extra: list[str]) -> object:
    return apply_overrides(preset("tiny"), [f"runs_dir={tmp}", f"run_name={name}", *extra])
