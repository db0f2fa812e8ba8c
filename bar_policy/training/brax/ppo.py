"""The default backend: PPO on the MJX env, JAX end to end, data-parallel over every device.

The algorithm is brax's (``bar_policy.training.brax.learner``: networks, loss, running statistics, data
layout). The loop around it is ours, for what ``ppo.train`` cannot give: checkpoints with the optimizer state
and step count (exact resume), progress lines with success rate and ETA, a wall-clock budget, the task's
evaluation ratios on fresh seeds, several hosts, and a fast start.

Programs (``jit`` of ``shard_map`` over the mesh of ``bar_policy.training.parallel``; env slots sharded,
learner state replicated), each compiled once, ahead of time and concurrently, by the start-up's one call
(``startup.compiled.compile_programs``; ``brax.programs.to_compile`` gives their order):

- ``init(key) -> state``: fresh params, Adam state, normaliser.
- ``reset(key, model_key) -> envs``: every env slot reset, with its randomised model's key kept beside its
  state. Slot ``i`` of ``num_envs`` gets key ``i`` of ``split(key, num_envs)`` whatever the device count, so
  every slot has its own model over the whole global batch (and 1, 2 or 8 devices draw the same models).
- ``rollout(state, envs, key, i, weights) -> envs, transitions, sums`` and ``update(state, transitions, key,
  i) -> state, losses``: PPO iteration ``i`` of an epoch keyed ``key`` (envs, then state donated).
  ``weights`` are the reward weights (``envs.reward_weights``): an argument, so a run that changes one
  loads the compiled programs (the executable key holds the terms' names, not their values). An epoch
  (``iters_per_epoch`` iterations, one progress line) is ``training.brax.state.run_epoch``: the calls queue
  on the device, with one host sync at its end. Two programs, not one scan over both: they compile side by
  side (H100, reach: all ready 26.5 s after the start of their compiles instead of the one epoch program's
  35.5 s, both beside the evaluation's; ``bench/program_split.py``, 2026-11-27) and load sooner (3.0 s
  instead of 3.8 s).
- ``evaluate(params, key, model_key, weights) -> metrics``: one deterministic episode in each of
  ``num_eval_envs`` slots (sharded too), without the in-step reset; every process takes part.

The evaluation is traced and compiled on a worker thread, so the training start waits for neither its
trace nor its compile. The evaluation at step 0, of the initial params (re-created by ``init`` from the same
key), runs as ``eval.initial`` says: ``end`` (default) after the last periodic evaluation, so it costs
nothing on the way to the first trained policy; ``start`` at the first epoch end where the evaluation is
ready; ``off`` never. Either way it is recorded as step 0, first in ``BraxTrainResult.evals``. Each
evaluation that ranks above every earlier one keeps a host copy of its params
(``bar_policy.training.best``): ``BraxTrainResult.best``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Generator
from typing import Any

import jax
import numpy as np

from bar_policy.training.brax.ignored_settings import brax_not_applied
from bar_policy.training.brax.programs import _policy_params, set_up
from bar_policy.training.brax.result import BraxTrainResult
from bar_policy.training.brax.state import _LINES_PER_EVAL, BraxRun
from bar_policy.training.checkpoint import Checkpoint, restore_state
from bar_policy.training.config import TrainConfig
from bar_policy.training.evaluations import Evaluations
from bar_policy.training.records import NotApplied, Record, Resumed, Said
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.compiled import compile_programs
from bar_policy.training.startup.session import StartUp

__all__ = ["train_brax"]


def train_brax(
    env: Any,
    cfg: TrainConfig,
    *,
    evaluations: Evaluations,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    resume: Checkpoint | None = None,
    start: StartUp | None = None,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
) -> Generator[Record, Any, BraxTrainResult]:
    """Train with brax PPO pieces on every device; see the module docstring.

    A generator: it yields what the run reports as it trains (``training.records``; ``RunLogger.follow``
    reports them and answers) and returns the result.

    Args:
        env: unwrapped env (``reset``/``step``, ``observation_size``, ``action_size``, ``episode_length``).
        cfg: the run's config (``cfg.ppo``, ``cfg.network``, ``cfg.eval``, ...).
        evaluations: the run's evaluations (``training.evaluations``), which every evaluation joins.
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)`` domain randomiser, or None.
        resume: the checkpoint the run resumes (``checkpoint.read_checkpoint``), restored into the
            training state; None: a fresh start.
        start: the run's start-up (``startup.session.StartUp``: its breakdown, reported once the first epoch
            is done and every program compiled, and its executable cache); None: a fresh one, no cache.
        eval_env: the env every evaluation runs (the task's held-out variant, ``evaluation_env()``) with
            ``eval_randomizer``; None: ``env`` with ``randomizer``.
        eval_randomizer: the model randomiser of ``eval_env`` (None: its nominal model).

    Returns:
        The trained params and a record of the run.
    """
    t_start = time.monotonic()
    start = start or StartUp()
    # Set-up: the mesh, the learner, its programs, compiling on worker threads from the one call on.
    with start.timer.phase(sb.PROGRAMS):
        setup = set_up(env, cfg, wrap_fn, randomizer, eval_env, eval_randomizer)
    programs = compile_programs(setup.to_compile(), start)
    yield NotApplied(tuple(brax_not_applied(cfg)))  # rsl-rl-only settings a brax run ignores
    with start.timer.phase(sb.WAIT):
        state = None
        if resume is not None:
            state = restore_state(resume, setup.template)
            yield Resumed(resume.path, resume.env_steps, resume.iteration, resume.changes)
        run = BraxRun(cfg, env, setup.dp, programs, setup.weights, resume, state, evaluations)

    # The loop: rollout -> update for an epoch of iterations, then its progress line, and every
    # _LINES_PER_EVAL epochs an evaluation (and a checkpoint).
    total_iters = math.ceil(cfg.ppo.num_timesteps / cfg.ppo.steps_per_iteration)
    start_steps, t_loop = run.env_steps, time.monotonic()
    while run.iteration < total_iters:
        epoch = run.rollout_and_update()
        over_budget = _agreed((yield epoch))
        last = run.iteration >= total_iters or over_budget
        eval_due = last or run.epochs % _LINES_PER_EVAL == 0
        # eval.initial=start: the step-0 evaluation runs at the first epoch end where the evaluation
        # program is ready, and always before the first periodic one. Under jax.distributed it was compiled
        # before the start on every process, so every process takes the same branch.
        step0_s = None
        if run.eval_at_start and (eval_due or programs.ready("evaluate")):
            step0_s = yield from run.evaluate_initial()
        report = programs.epoch_ended(
            run.epoch_s,
            ended_at=run.epoch_end,
            step=run.env_steps,
            step0_s=step0_s,
            step0_waiting=run.eval_at_start,
            eval_due=eval_due,
            eval_programs=("evaluate",),
        )
        if report is not None:
            yield report
        if eval_due:
            yield from run.evaluate(_policy_params(run.ts), run.env_steps)
            if last or (cfg.checkpoint_every and (run.epochs // _LINES_PER_EVAL) % cfg.checkpoint_every == 0):
                yield run.checkpoint()
        if over_budget and run.iteration < total_iters:
            yield Said((f"stopping: wall-clock budget of {cfg.max_minutes} min reached",))
            break
    programs["evaluate"]  # surface a compile error even when no evaluation ran
    report = programs.report(run.env_steps)  # unless reported in the loop
    if report is not None:
        yield report
    loop_s = time.monotonic() - t_loop
    if run.eval_at_end:  # eval.initial=end: the untrained policy, once the trained one is out
        yield Said(("step-0 evaluation (the untrained policy; after training: --eval.initial end)",))
        yield from run.evaluate_initial()
    train_seconds = time.monotonic() - t_start
    if run.epochs:
        yield Said(
            (
                f"trained {run.env_steps - start_steps:,} env steps in {loop_s:.1f} s of loop "
                f"({train_seconds:.1f} s with setup and compile)",
            )
        )
    return run.result(setup.learner, setup.prior, start_steps, train_seconds)


def _agreed(over: bool) -> bool:
    """Process 0's answer to whether the next epoch would overrun the budget, on every process."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        return bool(multihost_utils.broadcast_one_to_all(np.asarray(over)))
    return over
