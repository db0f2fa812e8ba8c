"""The rsl-rl backend's entry, torch-free: its jax programs compile before torch's side is imported.

``run_rsl_rl`` is what ``training.run`` calls (the brax backend's counterpart is ``brax.ppo.train_brax``):
the envs' programs first (``rsl_rl.programs.prepare_rsl_rl``: traced, lowered, compiling on worker threads),
then ``rsl_rl.backend`` imported (torch, rsl_rl, tensordict: seconds of the main thread, which then overlap
the compiles; ``tests/training/test_rsl_rl_start.py``), then its loop, ``backend.train_rsl_rl``.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from pathlib import Path
from typing import Any

from bar_policy.training.checkpoint import Checkpoint
from bar_policy.training.config import TrainConfig
from bar_policy.training.evaluations import Evaluations
from bar_policy.training.records import Record
from bar_policy.training.rsl_rl.programs import prepare_rsl_rl
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.session import StartUp

__all__ = ["run_rsl_rl"]


def run_rsl_rl(
    env: Any,
    cfg: TrainConfig,
    *,
    evaluations: Evaluations,
    wrap_fn: Callable[..., Any] | None = None,
    randomizer: Callable[..., Any] | None,
    resume: Checkpoint | None = None,
    start: StartUp | None = None,
    eval_env: Any | None = None,
    scalars_dir: Path | None = None,
) -> Generator[Record, Any, Any]:
    """The rsl-rl trainer as ``run`` calls it; the arguments of ``brax.ppo.train_brax``, and ``scalars_dir``.

    The jax programs first (traced, lowered, compiling on worker threads), then torch's side imported
    (``rsl_rl.backend``: seconds of this thread, overlapping the compiles); returns ``backend.train_rsl_rl``,
    the generator that trains (``scalars_dir``: where rsl-rl's runner logger writes the scalars).
    """
    start = start or StartUp()
    with start.timer.phase(sb.RSL_PROGRAMS):
        programs = prepare_rsl_rl(
            env, cfg, wrap_fn=wrap_fn, randomizer=randomizer, eval_env=eval_env, start=start
        )
    with start.timer.phase(sb.RSL_IMPORTS):
        from bar_policy.training.rsl_rl.backend import train_rsl_rl
    return train_rsl_rl(
        env,
        cfg,
        evaluations=evaluations,
        programs=programs,
        randomizer=randomizer,
        resume=resume,
        start=start,
        eval_env=eval_env,
        scalars_dir=scalars_dir,
    )
