"""The trainer's programs on one device, ready to lower: the set-up ``compile_options.py`` and
``program_split.py`` share (a fresh process each, on an empty compile cache with the shipped seeds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class OneDevice:
    """A preset's env, learner and programs on one device, with the abstract arguments to lower them."""

    cfg: Any
    env: Any
    randomizer: Any
    """The env's model randomiser (``envs.get_randomizer``)."""
    dp: Any
    learner: Any
    progs: Any
    """``training.brax.programs.make_programs``'s ``Programs``."""
    fused: Any
    """The one-program epoch of before 2026-11-27 (``fused_epoch``)."""
    iters: int
    """Iterations per epoch of ``fused``."""
    key_abs: Any
    i_abs: Any
    ts_abs: Any
    envs_abs: Any
    reset: Any
    """The reset program, lowered (its ``out_info`` gave ``envs_abs``)."""
    w_abs: Any
    """The reward weights' abstract argument (the rollout's and the evaluation's last)."""
    weights: Any
    """The reward weights, replicated (``envs.reward_weights.weights(env)``)."""
    seed_line: str
    """What the autotune seed did (``SeedOutcome.line``)."""


def one_device(args: Any, cache_dir: str, iters: int = 0) -> OneDevice:
    """Compile cache at ``cache_dir`` (seeded), then the programs of the config that ``args`` (a bench's
    ``config_args.add_config_args`` arguments) names.

    ``iters``: the fused epoch's iterations (0: the trainer's, ``epoch_iterations``).
    """
    import jax
    import numpy as np
    from config_args import config_of, load_env
    from fused_epoch import fused_epoch
    from jax.sharding import Mesh

    from bar_policy import envs
    from bar_policy.envs.reward_weights import weights
    from bar_policy.training.brax.learner import make_learner
    from bar_policy.training.brax.programs import epoch_iterations, make_programs
    from bar_policy.training.parallel import AXIS, DataParallel
    from bar_policy.training.startup.autotune import seed_autotune_cache
    from bar_policy.training.startup.compiler import configure_compile_cache

    seed_line = seed_autotune_cache(configure_compile_cache(True, cache_dir)).line()
    cfg = config_of(args)
    env = load_env(args.env, cfg)
    randomizer = envs.get_randomizer(args.env, env.config)
    wrap = envs.wrap_for_brax_training
    dp = DataParallel(Mesh(np.asarray(jax.devices()[:1]), (AXIS,)))
    learner = make_learner(env.observation_size, env.action_size, cfg.ppo, cfg.network)
    iters = iters or epoch_iterations(cfg)
    progs = make_programs(env, cfg, learner, dp, wrap, randomizer)
    key_abs = dp.abstract(np.zeros(2, np.uint32), sharded=False)
    reset = progs.reset.trace(key_abs, key_abs).lower()
    return OneDevice(
        cfg=cfg,
        env=env,
        randomizer=randomizer,
        dp=dp,
        learner=learner,
        progs=progs,
        fused=fused_epoch(env, cfg, learner, dp, wrap, randomizer, iters),
        iters=iters,
        key_abs=key_abs,
        i_abs=dp.abstract(np.zeros((), np.int32), sharded=False),
        ts_abs=dp.abstract(jax.eval_shape(learner.init, key_abs), sharded=False),
        envs_abs=dp.abstract(reset.out_info, sharded=True),
        reset=reset,
        w_abs=dp.abstract(weights(env), sharded=False),
        weights=dp.replicate(weights(env)),
        seed_line=seed_line,
    )
