"""One training run end to end: env, run directory, backend, final evaluation, ONNX export, summary.

``run(cfg)`` is what ``bar-train`` (``python train/ppo.py``) calls after parsing. The run directory
``<runs_dir>/<name>/`` receives ``config.json`` (the resolved training and env config), ``metrics.jsonl``,
``tb/`` (TensorBoard), ``checkpoints/step_<N>.msgpack``, ``policy.onnx`` and ``final_eval.json``. Each of
them carries the run's provenance (``bar_policy.provenance``: commit, dirty flag, library versions, the
command): ``config.json`` and ``final_eval.json`` under ``provenance``, ``metrics.jsonl`` as a
``{"kind": "provenance"}`` line at each (re)start, the checkpoint sidecars through the config record, the
ONNX files as ``bar.provenance``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bar_policy.training.best import finish_best
from bar_policy.training.config import TrainConfig, config_to_dict
from bar_policy.training.distributed import init_distributed, local_default_devices, shutdown_distributed
from bar_policy.training.progress import RunLogger, format_duration, format_eval, format_steps
from bar_policy.training.run_header import setting_lines
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.session import StartUp

__all__ = ["RunSummary", "evaluation_set", "final_eval_line", "init_distributed", "resolve_run_dir", "run"]


@dataclass(frozen=True, kw_only=True)
class RunSummary:
    """What a run produced."""

    run_dir: Path
    """The run directory."""
    env_steps: int
    """Total env steps trained (including those before a resume)."""
    wall_s: float
    """Wall time from ``run`` start to the end of the final evaluation, s."""
    train_sps_end_to_end: float
    """Env steps of this run / wall time of training (compile and evaluations included), steps/s."""
    final_eval: dict[str, float]
    """Final evaluation (``success_rate``, ``episode_reward``, ... over ``final_eval_envs`` episodes)."""
    final_eval_on: str = ""
    """What the final evaluation ran on (``evaluation_set``: episodes, held-out set or training env)."""
    time_to_threshold_s: float | None
    """Seconds from start to the first evaluation at or above ``eval.success_threshold`` (None: never)."""
    onnx_path: Path | None
    """Exported policy, if exported."""
    export: dict[str, Any]
    """Export record (parity error, size)."""
    params: Any = None
    """The trained policy's parameters on the host (brax: ``(normalizer, policy, value)``; rsl-rl: None)."""
    result: Any = None
    """The backend's result (``BraxTrainResult`` / ``RslRlTrainResult``): evaluate or export again, or
    reach ``result.best``, without retraining."""
    best: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The best evaluated iterate (``bar_policy.training.best.finish_best``): ``step``, ``is_last``, and
    when it is not the last iterate its ``final_eval`` and ``onnx``."""


def evaluation_set(episodes: float, *, held_out: bool) -> str:
    """What an evaluation ran on, for its printed label.

    ``episodes`` on the task's held-out evaluation env (``held_out``: its ``evaluation_env()``, evaluated on
    its nominal model) or fresh episodes of the training env (its randomisation kept).
    """
    if held_out:
        return f"{episodes:,.0f} episodes of the held-out evaluation set, nominal model"
    return f"{episodes:,.0f} fresh episodes, randomised as in training"


def final_eval_line(env_steps: int, evaluated_on: str, final: dict[str, float]) -> str:
    """The run's last evaluation, labelled: ``final evaluation (N env steps, on <what>): <figures>``."""
    return f"final evaluation ({env_steps:,} env steps, on {evaluated_on}): {format_eval(final)}"


def resolve_run_dir(cfg: TrainConfig, *, check: bool = True) -> Path:
    """``runs_dir/run_name``; an unnamed resume continues in the resumed run's directory.

    ``check=False`` skips the refusal of a used directory (processes other than 0, which write nothing
    and may see process 0's files already).
    """
    if cfg.run_name:
        run_dir = Path(cfg.runs_dir) / cfg.run_name
        if check and not cfg.resume and (run_dir / "metrics.jsonl").exists():
            # Appending a second run to the same metrics.jsonl mixes two curves (seen on a reused machine).
            raise ValueError(
                f"run directory {run_dir} already holds a run; choose another --run-name or --resume it"
            )
        return run_dir
    if cfg.resume:
        p = Path(cfg.resume)
        if p.is_file():
            p = p.parent
        return p.parent if p.name == "checkpoints" else p
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(cfg.runs_dir) / f"{cfg.env_name}-{cfg.backend}-{stamp}"


def _device_record() -> dict[str, Any]:
    """The run's devices, and XLA's flags as the run set them (``backend_env``) as ``xla_flags``.

    The flags choose how the programs run (command buffers, their loops): a speed is read with them.
    """
    import jax

    return {
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.local_devices()],
        "device_kind": jax.local_devices()[0].device_kind,
        "process_count": jax.process_count(),
        "host": platform.node(),
        "jax": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def _open_run(cfg: TrainConfig, env: Any, is_main: bool, notes: list[str]) -> tuple[Path, RunLogger, dict]:
    """The run directory, its logger and the config record; process 0 writes ``config.json`` and the header.

    ``notes`` are printed after the run line. Returns ``(run_dir, logger, record)``; the record holds the
    ``provenance``, the ``train`` and ``env`` configs and the ``device``.
    """
    import jax

    from bar_policy.provenance import collect, describe

    run_dir = resolve_run_dir(cfg, check=is_main)
    logger = RunLogger(
        run_dir, cfg.ppo.num_timesteps, enabled=is_main, logger=cfg.logger, wandb_project=cfg.wandb_project
    )
    provenance = collect()
    record = {
        "provenance": provenance,
        "train": config_to_dict(cfg),
        "env": json.loads(json.dumps(dataclasses.asdict(env.config), default=list))
        if dataclasses.is_dataclass(getattr(env, "config", None))
        else {},
        "device": _device_record(),
    }
    if is_main:
        (run_dir / "config.json").write_text(json.dumps(record, indent=2, sort_keys=True))
        logger.note("provenance", {"provenance": provenance})
        logger.print(describe(provenance)[0])
        logger.print(
            f"run {run_dir} | {cfg.env_name} ({env.observation_size} obs, {env.action_size} actions, "
            f"dt {env.dt} s) | backend {cfg.backend} | {record['device']['device_kind']} x "
            f"{jax.device_count()} | {format_steps(cfg.ppo.num_timesteps)} steps, {cfg.ppo.num_envs} envs"
        )
        for line in setting_lines(cfg, getattr(env, "config", None), _env_default(cfg.env_name)):
            logger.print(line)
        for line in notes:
            logger.print(line)
    return run_dir, logger, record


def _env_default(name: str) -> Any:
    """The registered env's default config (None for a name the registry lacks: a test's stand-in)."""
    from bar_policy import envs

    return envs.default_config(name) if name in envs.ALL_ENVS else None


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
    """``run`` up to the distributed shutdown."""
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
                env = envs.load(cfg.env_name, config=env_config, overrides=list(cfg.env_overrides) or None)
            randomizer = envs.get_randomizer(cfg.env_name, env.config)
        # The task's evaluation env (LiteTrack: held-out clips, nominal physics, as the ship gate's sim
        # target); a distinct one is evaluated without model randomisation.
        eval_env = env.evaluation_env() if hasattr(env, "evaluation_env") else None
        eval_env = None if eval_env is env else eval_env
    is_main = jax.process_index() == 0
    with timer.phase(sb.RUN_RECORD):
        run_dir, logger, record = _open_run(cfg, env, is_main, start.notes)
        for line in start.open(cfg, record, env):  # the autotune seeding waited for; the executable cache
            logger.print(line)
    logger.t0 = timer.origin
    logger.evaluated_on = "held-out set" if eval_env is not None else ""
    start.say = logger.print  # the start-up says what it is doing while its programs compile
    provenance = record["provenance"]

    ckpt_dir = str(run_dir / "checkpoints")
    # The trainer yields what it reports as it trains; the logger reports each record as it comes.
    if cfg.backend == "brax":
        trainer = train_brax(
            env, cfg, wrap_fn=envs.wrap_for_brax_training, randomizer=randomizer,
            checkpoint_dir=ckpt_dir, config_record=record, start=start, eval_env=eval_env,
        )  # fmt: skip
    else:
        trainer = run_rsl_rl(
            env, cfg, wrap_fn=envs.wrap_for_brax_training, randomizer=randomizer,
            checkpoint_dir=ckpt_dir, config_record=record, start=start, eval_env=eval_env,
            scalars_dir=logger.tb_dir if logger.writes_scalars else None,
        )  # fmt: skip
    result = logger.follow(trainer)

    # Every process evaluates (the brax evaluation is one program over all devices); process 0 reports.
    final = result.final_evaluation(cfg.final_eval_envs, seed=cfg.seed + 10_000)
    # The best iterate is evaluated on the same fresh seeds, so the two figures compare fairly.
    best_args = {"final_step": result.env_steps, "episodes": cfg.final_eval_envs, "seed": cfg.seed + 10_000}
    if not is_main:
        finish_best(result, export_to=None, **best_args)
        return RunSummary(
            run_dir=run_dir,
            env_steps=result.env_steps,
            wall_s=time.monotonic() - t0,
            train_sps_end_to_end=result.run_env_steps / max(result.train_seconds, 1e-9),
            final_eval=final,
            time_to_threshold_s=result.time_to_threshold_s,
            onnx_path=None,
            export={},
            params=getattr(result, "params", None),
            result=result,
        )

    logger.log(result.env_steps, final, kind="final")
    evaluated_on = evaluation_set(final.get("episodes", cfg.final_eval_envs), held_out=eval_env is not None)
    logger.print(final_eval_line(result.env_steps, evaluated_on, final))
    sps = result.run_env_steps / max(result.train_seconds, 1e-9)
    training_record = {
        "iterate": "last",
        "backend": cfg.backend,
        "env_name": cfg.env_name,
        "env_steps": result.env_steps,
        "train_seconds": round(result.train_seconds, 2),
        "train_sps_end_to_end": round(sps, 1),
        "time_to_threshold_s": result.time_to_threshold_s,
        "final_eval": final,
        "preset": cfg.preset,
        "seed": cfg.seed,
        "device": record["device"]["device_kind"],
        "device_count": jax.device_count(),
        "network": config_to_dict(cfg)["network"],
        "env_overrides": list(cfg.env_overrides),
    }
    export: dict[str, Any] = {}
    onnx_path: Path | None = None
    if cfg.export_onnx:
        onnx_path = Path(cfg.onnx_path) if cfg.onnx_path else run_dir / "policy.onnx"
    from bar_policy.training.metadata import policy_metadata

    best = finish_best(
        result,
        export_to=onnx_path,
        metadata_fn=lambda training: policy_metadata(env, training=training, provenance=provenance),
        training_record=training_record,
        **best_args,
    )
    if onnx_path is not None:
        meta = policy_metadata(env, training=training_record, provenance=provenance)
        export = result.export_onnx(meta, onnx_path)
    wall = time.monotonic() - t0
    final_record = {
        "final_eval": final,
        "final_eval_episodes": cfg.final_eval_envs,
        "final_eval_on": evaluated_on,
        "env_steps": result.env_steps,
        "wall_s": round(wall, 2),
        "train_seconds": round(result.train_seconds, 2),
        "train_sps_end_to_end": round(sps, 1),
        "time_to_threshold_s": result.time_to_threshold_s,
        "success_threshold": cfg.eval.success_threshold,
        "evals": result.evals,
        "export": export,
        "best_iterate": best,
        "provenance": provenance,
        "config": record,
        "startup": timer.report,
    }
    (run_dir / "final_eval.json").write_text(json.dumps(final_record, indent=2, sort_keys=True))
    summary = RunSummary(
        run_dir=run_dir,
        env_steps=result.env_steps,
        wall_s=wall,
        train_sps_end_to_end=sps,
        final_eval=final,
        final_eval_on=evaluated_on,
        time_to_threshold_s=result.time_to_threshold_s,
        onnx_path=onnx_path,
        export=export,
        params=getattr(result, "params", None),
        result=result,
        best=best,
    )
    for line in summary_table(summary, cfg):
        logger.print(line)
    logger.close()
    return summary


def _best_text(best: dict[str, Any]) -> str:
    if not best or best.get("is_last", True):
        return "the last one (no earlier evaluation ranked higher)"
    fe = best["final_eval"]
    text = f"{best['step']:,} steps: final success {100 * fe.get('success_rate', math.nan):.2f}%"
    if "final_distance" in fe:
        text += f", fingertip distance {100 * fe['final_distance']:.2f} cm"
    return text + (f" -> {best['onnx']}" if "onnx" in best else " (not exported)")


def summary_table(s: RunSummary, cfg: TrainConfig) -> list[str]:
    """The end-of-run table (plain text)."""
    thr = f"{100 * cfg.eval.success_threshold:.0f}%"
    ttt = format_duration(s.time_to_threshold_s) if s.time_to_threshold_s is not None else "not reached"
    rows = [
        ("run directory", str(s.run_dir)),
        ("backend / preset", f"{cfg.backend} / {cfg.preset}"),
        ("env steps", f"{s.env_steps:,}"),
        ("wall time", format_duration(s.wall_s)),
        ("training env steps/s (end to end)", f"{s.train_sps_end_to_end:,.0f}"),
        (f"time to {thr} eval success", ttt),
        ("final evaluation", f"{s.env_steps:,} env steps, on {s.final_eval_on or '?'}"),
        ("final success rate", f"{100 * s.final_eval.get('success_rate', math.nan):.2f}%"),
        ("final episode reward", f"{s.final_eval.get('episode_reward', math.nan):.2f}"),
        *(
            [("final fingertip distance", f"{100 * s.final_eval['final_distance']:.2f} cm")]
            if "final_distance" in s.final_eval
            else []
        ),
        *(
            (f"final {k}", f"{v:.4g}")
            for k, v in s.final_eval.items()
            if k not in ("success_rate", "episode_reward", "episode_reward_std", "final_distance", "episodes")
        ),
        ("ONNX", str(s.onnx_path) if s.onnx_path else "not exported"),
        ("parity max abs error", f"{e:.2e}" if (e := s.export.get("max_abs_error")) is not None else "-"),
        ("best iterate", _best_text(s.best)),
    ]
    width = max(len(k) for k, _ in rows)
    bar = "-" * (width + 40)
    return [bar, *(f"{k:<{width}}  {v}" for k, v in rows), bar]
