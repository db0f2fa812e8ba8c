"""The default backend: PPO on the MJX env, JAX end to end, data-parallel over every device.

The algorithm is brax's (``bar_policy.training.brax.learner``: networks, loss, running statistics, data
layout). The loop around it is ours, for what ``ppo.train`` cannot give: checkpoints with the optimizer state
and step count (exact resume), progress lines with success rate and ETA, a wall-clock budget, the task's
evaluation ratios on fresh seeds, several hosts, and a fast start.

Programs (``jit`` of ``shard_map`` over the mesh of ``bar_policy.training.parallel``; env slots sharded,
learner state replicated), each compiled once, ahead of time and concurrently (``startup.compiler.Compiler``):

- ``init(key) -> state``: fresh params, Adam state, normaliser.
- ``reset(key, model_key) -> envs``: every env slot reset, with its randomised model's key kept beside its
  state. Slot ``i`` of ``num_envs`` gets key ``i`` of ``split(key, num_envs)`` whatever the device count, so
  every slot has its own model over the whole global batch (and 1, 2 or 8 devices draw the same models).
- ``rollout(state, envs, key, i, weights) -> envs, transitions, sums`` and ``update(state, transitions, key,
  i) -> state, losses``: PPO iteration ``i`` of an epoch keyed ``key`` (envs, then state donated).
  ``weights`` are the reward weights (``envs.reward_weights``): an argument, so a run that changes one
  loads the compiled programs (the executable key holds the terms' names, not their values). An epoch
  (``iters_per_epoch`` iterations, one progress line) is ``training.brax.programs.run_epoch``: the calls queue
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
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from bar_policy.envs import reward_weights
from bar_policy.training.best import BestKeeper
from bar_policy.training.brax.ignored_settings import brax_not_applied
from bar_policy.training.brax.learner import make_learner
from bar_policy.training.brax.programs import (
    _K_EPOCH,
    _K_EVAL,
    _K_EVAL_MODEL,
    _K_INIT,
    _K_MODEL,
    _K_RESET,
    _LINES_PER_EVAL,
    _host_params,
    _policy_params,
    action_prior,
    epoch_iterations,
    epoch_totals,
    host_key,
    make_programs,
    run_epoch,
)
from bar_policy.training.brax.result import BraxTrainResult
from bar_policy.training.checkpoint import load_checkpoint, resume_changes, save_checkpoint
from bar_policy.training.config import TrainConfig
from bar_policy.training.parallel import barrier, make_data_parallel
from bar_policy.training.progress import RunLogger, next_would_overrun
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compiler import Compiler, CompileStats
from bar_policy.training.startup.executable_cache import ExecutableCache

__all__ = ["train_brax"]


def train_brax(
    env: Any,
    cfg: TrainConfig,
    logger: RunLogger,
    *,
    wrap_fn: Callable[..., Any],
    randomizer: Callable[..., Any] | None,
    checkpoint_dir: str | None,
    config_record: dict[str, Any] | None = None,
    timer: StartupTimer | None = None,
    eval_env: Any | None = None,
    eval_randomizer: Callable[..., Any] | None = None,
    executable_cache: ExecutableCache | None = None,
) -> BraxTrainResult:
    """Train with brax PPO pieces on every device; see the module docstring.

    Args:
        env: unwrapped env (``reset``/``step``, ``observation_size``, ``action_size``, ``episode_length``).
        cfg: the run's config (``cfg.ppo``, ``cfg.network``, ``cfg.eval``, ``cfg.resume``, ...).
        logger: progress/metric sink (disabled on processes other than 0).
        wrap_fn: ``wrap_for_brax_training(env, episode_length=, action_repeat=, randomization_fn=)``.
        randomizer: ``(model, rng) -> (model, in_axes)`` domain randomiser, or None.
        checkpoint_dir: where checkpoints go (None: no checkpoints).
        config_record: JSON record stored in checkpoint sidecars.
        timer: start-up breakdown to add the compile phases to (printed once the first epoch is done and
            every program compiled, before the first evaluation at the latest).
        eval_env: the env every evaluation runs (the task's held-out variant, ``evaluation_env()``) with
            ``eval_randomizer``; None: ``env`` with ``randomizer``.
        eval_randomizer: the model randomiser of ``eval_env`` (None: its nominal model).
        executable_cache: load and store the programs' executables here (None: compile every run).

    Returns:
        The trained params and a record of the run.
    """
    ppo = cfg.ppo
    t_start = time.monotonic()
    timer = timer or StartupTimer()
    stats0 = CompileStats.get().snapshot()
    with timer.phase(sb.PROGRAMS):
        dp = make_data_parallel(cfg.distributed.max_devices_per_host)
        dp.check_divisible(
            **{
                "ppo.num_envs": ppo.num_envs,
                "ppo.batch_size": ppo.batch_size,
                "eval.num_eval_envs": cfg.eval.num_eval_envs,
            }
        )
        steps_per_iter = ppo.steps_per_iteration
        total_iters = math.ceil(ppo.num_timesteps / steps_per_iter)
        iters_per_epoch = epoch_iterations(cfg)

        prior = action_prior(env, cfg.network, cfg.env_name)
        learner = make_learner(env.observation_size, env.action_size, ppo, cfg.network, prior)
        programs = make_programs(env, cfg, learner, dp, wrap_fn, randomizer, eval_env, eval_randomizer)
        key_abs = dp.abstract(np.zeros(2, np.uint32), sharded=False)
        i_abs = dp.abstract(np.zeros((), np.int32), sharded=False)
        template = jax.eval_shape(learner.init, key_abs)
        ts_abs = dp.abstract(template, sharded=False)
    seed = cfg.seed

    # Trace each program here and compile it on a worker thread. The reset goes first (its outputs are the
    # rollout's inputs), the rollout (the longest compile) right after it, the update (its inputs are the
    # rollout's outputs, so the rollout is loaded here on a warm start), then the small init. Nothing waits
    # on the evaluation before the first epochs end, so it is traced on a worker too: on a warm compile cache
    # its trace is a third of what is left of the start-up, and it now overlaps the first epochs.
    compiler = Compiler(timer, executable_cache=executable_cache)
    reset_lowered = compiler.submit("reset", programs.reset, key_abs, key_abs)
    envs_abs = dp.abstract(reset_lowered.out_info, sharded=True)
    w_host = reward_weights.weights(env)  # the rollout's and evaluation's argument
    w_abs = dp.abstract(w_host, sharded=False)
    rollout_lowered = compiler.submit("rollout", programs.rollout, ts_abs, envs_abs, key_abs, i_abs, w_abs)
    data_abs = dp.abstract(rollout_lowered.out_info[1], sharded=True)
    compiler.submit("update", programs.update, ts_abs, data_abs, key_abs, i_abs, load_in_background=True)
    compiler.submit("init", programs.init, key_abs)
    evaluate_abs = (_policy_params(ts_abs), key_abs, key_abs, w_abs)
    compiler.submit("evaluate", programs.evaluate, *evaluate_abs, background=True)

    logger.not_applied(brax_not_applied(cfg))  # rsl-rl-only settings a brax run ignores: said and recorded
    env_steps, iteration = 0, 0
    with timer.phase(sb.WAIT):
        if cfg.resume:
            ckpt = load_checkpoint(cfg.resume, template)
            env_steps, iteration = ckpt.env_steps, ckpt.iteration
            ts = dp.replicate(ckpt.state)
            logger.print(f"resumed {ckpt.path} at {env_steps} env steps (iteration {iteration})")
            for line in resume_changes(ckpt.path, config_record):
                logger.print(line)
        else:
            ts = compiler.get("init")(dp.replicate(host_key(seed, _K_INIT)))
        model_key = dp.replicate(host_key(seed, _K_MODEL))
        envs = compiler.get("reset")(dp.replicate(host_key(seed, _K_RESET, iteration)), model_key)
        rollout, update = compiler.get("rollout"), compiler.get("update")
        iteration_index = [dp.replicate(np.int32(i)) for i in range(iters_per_epoch)]
        if jax.process_count() > 1:
            # Start together: a process still compiling in the background would reach the first
            # collective late, and CPU (gloo) collectives give up after 30 s.
            compiler.get("evaluate")
            barrier("bar_policy: programs compiled")

    eval_model_key = dp.replicate(host_key(seed, _K_EVAL_MODEL))
    weights = dp.replicate(w_host)

    def evaluator(params: Any, eval_seed: int) -> dict[str, float]:
        key = dp.replicate(host_key(eval_seed, _K_EVAL))
        metrics = compiler.get("evaluate")(dp.replicate(tuple(params[:2])), key, eval_model_key, weights)
        return {k: float(v) for k, v in dp.to_host(metrics).items()}

    last_eval_s = 0.0

    def device_eval(params: tuple[Any, Any], step: int) -> None:
        nonlocal last_eval_s
        t_eval = time.monotonic()
        m = compiler.get("evaluate")(
            params, dp.replicate(host_key(seed, _K_EVAL, step)), eval_model_key, weights
        )
        m = {k: float(v) for k, v in dp.to_host(m).items()}
        if step:  # the step-0 evaluation's time includes its compile
            last_eval_s = time.monotonic() - t_eval
        logger.record_eval(step, m, evals, time_to_threshold, cfg.eval.success_threshold)
        if keeper.offer(step, m, lambda: _host_params(dp.to_host(ts))):
            logger.print(f"  best so far: the parameters at {step:,} steps are kept")
        compiler.confirm()  # every loaded program has run: none is a suspect of a crash

    is_main = jax.process_index() == 0
    evals: list[dict[str, float]] = []
    time_to_threshold: list[float] = []

    def checkpoint(step: int, it: int) -> None:
        host = dp.to_host(ts)  # every process fetches its own replica; only process 0 writes
        if is_main and checkpoint_dir is not None:
            save_checkpoint(checkpoint_dir, host, env_steps=step, iteration=it, extra=config_record)

    start_steps = env_steps
    keeper = BestKeeper(start_steps, getattr(env, "task_name", None))
    # The step-0 evaluation: none after a resume. Every process decides alike (config and checkpoint), so
    # under jax.distributed all of them run it, collectively, at the same point.
    eval_at_start = iteration == 0 and cfg.eval.initial == "start"
    eval_at_end = iteration == 0 and cfg.eval.initial == "end"
    epochs_done = 0
    first_epoch_end = 0.0
    # With eval.initial=start the step-0 evaluation always runs within the start-up (which ends with it).
    step0_in_startup = eval_at_start
    startup_pending = True
    startup_end_s: float | None = None  # when the start-up ended (its report may come later)

    def report_startup() -> None:
        """Print and record the start-up breakdown (up to the first epoch's end, or the step-0 evaluation's).

        Called once every program is compiled or loaded, so that no row is still compiling: with the
        evaluation compiling beside the first epochs, that is just before the first evaluation at the
        latest (which would wait for its program anyway), so the record always precedes every evaluation's.
        """
        nonlocal startup_pending
        startup_pending = False
        stats1 = CompileStats.get().snapshot()
        until = sb.UNTIL_EVAL if step0_in_startup else sb.UNTIL_EPOCH
        compiles = {k: stats1[k] - stats0[k] for k in stats1}
        report = timer.finish(first_epoch_end, compiles, total_s=startup_end_s, until=until)
        for line in timer.lines(report):
            logger.print(line)
        logger.note("startup", {"step": env_steps, **report})

    def eval_at_zero() -> None:
        """The untrained policy's evaluation (its params re-created by ``init``), logged as step 0."""
        t_eval = time.monotonic()
        initial = compiler.get("init")(dp.replicate(host_key(seed, _K_INIT)))
        device_eval(_policy_params(initial), 0)
        if startup_pending:
            timer.add(sb.FIRST_EVAL, time.monotonic() - t_eval)

    t_loop = time.monotonic()
    while iteration < total_iters:
        t0 = time.monotonic()
        epoch_key = dp.replicate(host_key(seed, _K_EPOCH, iteration))
        ts, envs, metrics, stats = run_epoch(rollout, update, ts, envs, epoch_key, iteration_index, weights)
        metrics, stats = epoch_totals(*dp.to_host((metrics, stats)))
        dt = time.monotonic() - t0
        iteration += iters_per_epoch
        env_steps += iters_per_epoch * steps_per_iter
        epochs_done += 1
        steps_in_epoch = iters_per_epoch * steps_per_iter
        train_metrics = {
            **{f"loss/{k}": float(v) for k, v in metrics.items()},
            "episode_reward": float(stats[0]) / steps_in_epoch * env.episode_length,
            "success_rate": float(stats[1]) / max(float(stats[2]), 1.0),
            "sps": steps_in_epoch / dt,
        }
        logger.log(env_steps, train_metrics, kind="train")
        logger.progress(env_steps, steps_in_epoch / dt, train_metrics)
        if epochs_done == 1:
            timer.add(sb.FIRST_EPOCH, dt)
            first_epoch_end = timer.elapsed()
        elif eval_at_start:
            timer.add(sb.MORE_EPOCHS, dt)
        # Stop before an epoch that would end past the budget (its expected length: this epoch's, plus an
        # evaluation's when the next epoch ends with one), keeping room for one more evaluation when the
        # step-0 one runs after training.
        next_eval_due = (epochs_done + 1) % _LINES_PER_EVAL == 0
        evals_s = (last_eval_s if next_eval_due else 0.0) + (last_eval_s if eval_at_end else 0.0)
        over_budget = next_would_overrun(logger.elapsed(), dt + evals_s, 60 * cfg.max_minutes)
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils

            over_budget = bool(multihost_utils.broadcast_one_to_all(np.asarray(over_budget)))
        last = iteration >= total_iters or over_budget
        eval_due = last or epochs_done % _LINES_PER_EVAL == 0
        # eval.initial=start: the step-0 evaluation runs at the first epoch end where the evaluation
        # program is ready, and always before the first periodic one. Under jax.distributed it was
        # compiled before the start on every process, so every process takes the same branch.
        if eval_at_start and (eval_due or compiler.done("evaluate")):
            eval_at_start = False
            eval_at_zero()
        if startup_end_s is None and not eval_at_start:  # the start-up ends here (first epoch or step 0's)
            startup_end_s = timer.elapsed()
        if startup_pending and not eval_at_start and (eval_due or compiler.done("evaluate")):
            compiler.get("evaluate")  # an evaluation is due: it waits for the program anyway
            report_startup()  # the start-up ended with the first epoch (or step 0's evaluation)
        if eval_due:
            device_eval(_policy_params(ts), env_steps)
            n_evals = epochs_done // _LINES_PER_EVAL
            if last or (cfg.checkpoint_every and n_evals % cfg.checkpoint_every == 0):
                checkpoint(env_steps, iteration)
        if over_budget and not iteration >= total_iters:
            logger.print(f"stopping: wall-clock budget of {cfg.max_minutes} min reached")
            break
    compiler.get("evaluate")  # surface a compile error even when no evaluation ran
    if startup_pending and epochs_done:
        report_startup()
    loop_s = time.monotonic() - t_loop
    if eval_at_end:  # eval.initial=end: the untrained policy, once the trained one is out
        logger.print("step-0 evaluation (the untrained policy; after training: --eval.initial end)")
        eval_at_zero()
    train_seconds = time.monotonic() - t_start
    if epochs_done:
        logger.print(
            f"trained {env_steps - start_steps:,} env steps in {loop_s:.1f} s of loop "
            f"({train_seconds:.1f} s with setup and compile)"
        )
    return BraxTrainResult(
        params=_host_params(dp.to_host(ts)),
        make_policy=learner.make_policy,
        env_steps=env_steps,
        run_env_steps=env_steps - start_steps,
        train_seconds=train_seconds,
        evals=evals,
        time_to_threshold_s=time_to_threshold[0] if time_to_threshold else None,
        evaluator=evaluator,
        num_eval_envs=cfg.eval.num_eval_envs,
        activation=cfg.network.activation,
        best=keeper.best,
        prior=prior,
    )
