"""One training run end to end: start-up, env, run directory, trainer, final evaluation, export, summary.

``run(cfg)`` is what ``bar-train`` (``python train/ppo.py``) calls after parsing. It begins the start-up
(``startup.session.StartUp``), builds the env, opens the run directory (``run_dir.open_run``: its record,
logger and header), hands the backend's trainer to the logger (``RunLogger.follow``: the trainer yields what
it reports, ``training.records``) and ends with ``summary.finish_run`` (final evaluation, best iterate, ONNX
export, ``final_eval.json``, the summary table), the same for both backends. The run directory
``<runs_dir>/<name>/`` receives ``config.json`` (the resolved training and env config), ``metrics.jsonl``,
``tb/`` (TensorBoard), ``checkpoints/step_<N>.msgpack``, ``policy.onnx`` and ``final_eval.json``. Each of
them carries the run's provenance (``bar_policy.provenance``: commit, dirty flag, library versions, the
command): ``config.json`` and ``final_eval.json`` under ``provenance``, ``metrics.jsonl`` as a
``{"kind": "provenance"}`` line at each (re)start, the checkpoint sidecars through the config record, the
ONNX files as ``bar.provenance``.
"""

from __future__ import annotations

import time
from typing import Any

from bar_policy.training.checkpoint import read_checkpoint
from bar_policy.training.config import TrainConfig
from bar_policy.training.distributed import init_distributed, local_default_devices, shutdown_distributed
from bar_policy.training.evaluations import Evaluations
from bar_policy.training.run_dir import open_run
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.session import StartUp
from bar_policy.training.summary import RunSummary, finish_run

__all__ = ["RunSummary", "init_distributed", "run"]


def run(
    cfg: TrainConfig,
    *,
    env_config: Any | None = None,
    env: Any | None = None,
    started_at: float | None = None,
) -> RunSummary:
    """Train, evaluate and export as configured; returns the summary (also printed as a table).

    Under ``jax.distributed`` every process connects at the start and, once its part is done, shuts the
    session down in order (``training.distributed.shutdown_distributed``).

    Args:
        cfg: the resolved training config.
        env_config: a full env config object to use instead of the registry default (overrides in
            ``cfg.env_overrides`` still apply on top).
        env: an env object to train on instead of ``envs.load(cfg.env_name)`` (tests use a stand-in);
            it is trained without model randomisation.
        started_at: ``time.monotonic()`` of the process start (the command line passes it): progress
            times, time-to-threshold and the start-up breakdown then count from there, not from ``run``.
    """
    summary = _run(cfg, env_config=env_config, env=env, started_at=started_at)
    shutdown_distributed()
    return summary


def _run(cfg: TrainConfig, *, env_config: Any, env: Any, started_at: float | None) -> RunSummary:
    """``run`` up to the distributed shutdown: start up, build the env, open the run, train, finish."""
    t0 = time.monotonic()
    if cfg.backend == "rsl-rl" and cfg.distributed.num_processes > 1:
        raise ValueError(
            "the rsl-rl backend runs in one process on one device; use --backend brax for several"
        )
    # The start-up before jax's backend starts: backend environment, compile cache, jax.distributed, the
    # autotune seeding (on a thread, overlapping the env build).
    start = StartUp.begin(cfg, started_at)
    timer = start.timer
    with timer.phase(sb.IMPORTS):
        import jax

        # Full float32 products unless asked otherwise (a TF32 gradient destabilised Playground's runs).
        jax.config.update(
            "jax_default_matmul_precision", "highest" if cfg.matmul_precision == "highest" else None
        )

        from bar_policy import envs

        if cfg.backend == "brax":
            from bar_policy.training.brax.ppo import train_brax
        else:  # torch-free: it imports rsl_rl.backend (torch) once its programs are compiling
            from bar_policy.training.rsl_rl.entry import run_rsl_rl

    # The env's model build (bar_policy._phases.MODEL_BUILD) is its own row, taken out of this one.
    with timer.active(), timer.phase(sb.ENV_BUILD):
        randomizer = None
        if env is None:
            with local_default_devices():
                env, randomizer = envs.load_for_training(
                    cfg.env_name, config=env_config, overrides=list(cfg.env_overrides) or None
                )
        # The task's evaluation env (LiteTrack: held-out clips, nominal physics, as the ship gate's sim
        # target); a distinct one is evaluated without model randomisation.
        eval_env = env.evaluation_env() if hasattr(env, "evaluation_env") else None
        eval_env = None if eval_env is env else eval_env
    is_main = jax.process_index() == 0
    with timer.phase(sb.RUN_RECORD):
        run_dir, logger, record = open_run(cfg, env, start, is_main)
    logger.t0 = timer.origin
    logger.evaluated_on = "held-out set" if eval_env is not None else ""
    start.say = logger.print  # the start-up says what it is doing while its programs compile

    # The checkpoint a resume continues from, read before anything compiles (its changes said by the
    # trainer), and the run's evaluations, which both trainers record into.
    resume = read_checkpoint(cfg.resume, record) if cfg.resume else None
    first_step = resume.env_steps if resume is not None else 0
    evaluations = Evaluations(first_step, getattr(env, "task_name", None), cfg.eval.success_threshold)
    # The trainer yields what it reports as it trains; the logger reports each record as it comes.
    common = {
        "evaluations": evaluations,
        "wrap_fn": envs.wrap_for_brax_training,
        "randomizer": randomizer,
        "resume": resume,
        "start": start,
        "eval_env": eval_env,
    }
    if cfg.backend == "brax":
        trainer = train_brax(env, cfg, **common)
    else:  # rsl-rl's runner logger writes the scalars into the run's tb/ itself
        trainer = run_rsl_rl(env, cfg, **common, scalars_dir=logger.tb_dir if logger.writes_scalars else None)
    result = logger.follow(trainer)
    # The final evaluation, the best iterate, the export and the summary, alike for both backends.
    finish = finish_run(
        cfg,
        env,
        result,
        run_dir=run_dir,
        record=record,
        is_main=is_main,
        held_out=eval_env is not None,
        t0=t0,
        startup=timer.report,
    )
    summary = logger.follow(finish)
    logger.close()
    return summary
