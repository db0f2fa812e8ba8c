"""How a run ends: the final evaluation, the best iterate, the ONNX export, ``final_eval.json``, the summary.

``finish_run`` is ``training.run``'s last step, after the trainer returned, alike for both backends. Like
a trainer it is a generator (``training.records``): it yields the final evaluation (logged as ``final``, its
line printed) and the summary table, and returns the ``RunSummary``. Under ``jax.distributed`` every process
runs it (the brax evaluation is one program over all devices); only process 0 reports and writes.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bar_policy.training.best import best_onnx_path
from bar_policy.training.config import TrainConfig, config_to_dict
from bar_policy.training.progress import format_duration, format_eval
from bar_policy.training.records import Final, Record, Said

if TYPE_CHECKING:
    from bar_policy.deploy.metadata import PolicyMetadata

__all__ = [
    "RunSummary",
    "evaluation_set",
    "final_eval_line",
    "finish_best",
    "finish_run",
    "summary_table",
]


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
    """The best evaluated iterate (``finish_best``): ``step``, ``is_last``, and
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


def finish_best(
    result: Any,
    *,
    final_step: int,
    episodes: int,
    seed: int,
    export_to: Path | None,
    metadata: PolicyMetadata | None = None,
) -> dict[str, Any]:
    """Evaluate (and export) the run's best iterate when it is not the last one; returns its record.

    Under ``jax.distributed`` every process calls this (the brax evaluation is one program over all
    devices); only the caller that passes ``export_to`` writes a file.

    Args:
        result: a backend result with ``best`` (``BestIterate`` or None), ``at(params)`` (the same result
            with other parameters), ``final_evaluation`` and ``export_onnx``.
        final_step: env steps of the last iterate.
        episodes: episodes of the final evaluation (same as the last iterate's).
        seed: seed of the final evaluation (same as the last iterate's, for a paired comparison).
        export_to: the last iterate's ONNX path; the best one goes to ``best_onnx_path(export_to)``. None:
            no export.
        metadata: the last iterate's ONNX metadata (required with ``export_to``); the best one's is the same
            with a training record that copies the last one's with its own step, final evaluation and
            selection.

    Returns:
        ``{"step", "is_last"}``, plus, when the best is not the last iterate, ``eval_during_training``,
        ``final_eval``, and with an export ``onnx`` and ``export``.
    """
    best = getattr(result, "best", None)
    if best is None or best.step == final_step:
        return {"step": final_step, "is_last": True}
    chosen = result.at(best.params)
    final = chosen.final_evaluation(episodes, seed=seed)
    record: dict[str, Any] = {
        "step": best.step,
        "is_last": False,
        "eval_during_training": best.metrics,
        "final_eval": final,
    }
    if export_to is not None:
        if metadata is None:
            raise ValueError("finish_best: export_to needs metadata")
        path = best_onnx_path(export_to)
        training = {
            **metadata.training,
            "env_steps": best.step,
            "final_eval": final,
            "iterate": "best",
            "selected_by": "the ship gate's score of the held-out evaluations during training (least "
            "excess beyond the thresholds, then accuracy), or success rate then reward without them",
            "eval_during_training": best.metrics,
        }
        from bar_policy.training.metadata import with_training  # the export's side: onnx, deploy metadata

        record["onnx"] = str(path)
        record["export"] = chosen.export_onnx(with_training(metadata, training), path)
    return record


def finish_run(
    cfg: TrainConfig,
    env: Any,
    result: Any,
    *,
    run_dir: Path,
    record: dict[str, Any],
    is_main: bool,
    held_out: bool,
    t0: float,
    startup: dict[str, Any] | None,
) -> Generator[Record, Any, RunSummary]:
    """Evaluate, export and summarise a trained ``result`` (``BraxTrainResult`` / ``RslRlTrainResult``).

    Args:
        cfg: the run's config (``final_eval_envs``, ``seed``, ``export_onnx``, ``onnx_path``, ...).
        env: the env trained on (the ONNX metadata reads it: ``metadata.policy_metadata``).
        result: the trainer's result.
        run_dir: the run directory (``final_eval.json``, ``policy.onnx`` unless ``cfg.onnx_path``).
        record: the run's config record (``run_dir.open_run``).
        is_main: process 0, the one that reports and writes.
        held_out: whether the evaluations ran on the task's held-out evaluation env.
        t0: ``time.monotonic()`` at the start of ``run`` (the summary's wall time counts from it).
        startup: the start-up breakdown's record (``final_eval.json``'s ``startup``).
    """
    import jax

    # Every process evaluates (the brax evaluation is one program over all devices); process 0 reports.
    final = result.final_evaluation(cfg.final_eval_envs, seed=cfg.seed + 10_000)
    evaluated_on = evaluation_set(final.get("episodes", cfg.final_eval_envs), held_out=held_out)
    if is_main:
        yield Final(result.env_steps, final, final_eval_line(result.env_steps, evaluated_on, final))
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
    onnx_path: Path | None = None
    meta = None
    if is_main and cfg.export_onnx:
        from bar_policy.training.metadata import policy_metadata

        onnx_path = Path(cfg.onnx_path) if cfg.onnx_path else run_dir / "policy.onnx"
        meta = policy_metadata(env, training=training_record, provenance=record["provenance"])
    # The best iterate is evaluated on the same fresh seeds, so the two figures compare fairly (by every
    # process; exported by process 0).
    best_args = {"final_step": result.env_steps, "episodes": cfg.final_eval_envs, "seed": cfg.seed + 10_000}
    best = finish_best(result, export_to=onnx_path, metadata=meta, **best_args)
    export = result.export_onnx(meta, onnx_path) if onnx_path is not None else {}
    wall = time.monotonic() - t0
    summary = RunSummary(
        run_dir=run_dir,
        env_steps=result.env_steps,
        wall_s=wall,
        train_sps_end_to_end=sps,
        final_eval=final,
        final_eval_on=evaluated_on if is_main else "",
        time_to_threshold_s=result.time_to_threshold_s,
        onnx_path=onnx_path,
        export=export,
        params=getattr(result, "params", None),
        result=result,
        best=best if is_main else {},
    )
    if not is_main:
        return summary
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
        "provenance": record["provenance"],
        "config": record,
        "startup": startup,
    }
    (run_dir / "final_eval.json").write_text(json.dumps(final_record, indent=2, sort_keys=True))
    yield Said(tuple(summary_table(summary, cfg)))
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
