"""``BraxTrainResult``: what ``train_brax`` returns (params, evaluations, the best iterate) and its export."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bar_policy.obs.action_prior import Prior
from bar_policy.training.best import BestIterate

__all__ = ["BraxTrainResult"]


@dataclass(frozen=True, kw_only=True)
class BraxTrainResult:
    """Outcome of ``train_brax``."""

    params: tuple[Any, Any, Any]
    """``(normalizer, policy, value)`` params on the host (brax's layout)."""
    make_policy: Callable[..., Any]
    """brax's ``make_inference_fn(networks)``: ``make_policy(params, deterministic) -> policy(obs, key)``."""
    env_steps: int
    """Total env steps trained (including those before a resume)."""
    run_env_steps: int
    """Env steps trained in this process's run (excluding those before a resume)."""
    train_seconds: float
    """Wall time of the training loop in this run, s (compile and evaluations included)."""
    evals: list[dict[str, float]] = field(default_factory=list)
    """Evaluation records (``step``, ``time_s``, ``success_rate``, ``episode_reward``, ...), in step order
    (step 0 first, whenever it ran: ``eval.initial``)."""
    time_to_threshold_s: float | None = None
    """Seconds from logger start to the first evaluation at or above the success threshold (a step-0
    evaluation run after training does not count: ``training.evaluations``)."""
    evaluator: Callable[[Any, int], dict[str, float]] | None = None
    """``evaluator(host_params, seed)``: the run's compiled evaluation (``num_eval_envs`` episodes)."""
    num_eval_envs: int = 0
    """Episodes per ``evaluator`` call."""
    activation: str = "swish"
    """Hidden activation of the networks (for export)."""
    best: BestIterate | None = None
    """The best evaluated iterate of this run (``bar_policy.training.best``); None when nothing was
    evaluated after training started."""
    prior: Prior | None = None
    """The policy's action prior (``NetworkConfig.action_prior``; for export), None without one."""

    def at(self, params: tuple[Any, Any, Any]) -> BraxTrainResult:
        """The same result with other parameters (e.g. ``best.params``), to evaluate or export them."""
        return dataclasses.replace(self, params=params)

    def final_evaluation(self, episodes: int, seed: int) -> dict[str, float]:
        """Evaluate on ``episodes`` fresh episodes (rounded up to whole evaluator batches).

        Reuses the compiled evaluator, so no new compile; rates are averaged over equal-size batches. Under
        ``jax.distributed`` every process must call it (the evaluation is one program over all devices).
        """
        if self.evaluator is None:
            raise ValueError("this result has no evaluator")
        rounds = max(1, math.ceil(episodes / self.num_eval_envs))
        runs = [self.evaluator(self.params, seed + i) for i in range(rounds)]
        out = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
        out["episodes"] = float(rounds * self.num_eval_envs)
        return out

    def export_onnx(self, metadata: Any, path: str | Any) -> dict[str, Any]:
        """Export the deterministic policy with the parity gate (``export.policy.export_brax_policy``)."""
        from bar_policy.export.policy import export_brax_policy

        return export_brax_policy(
            self.params, self.make_policy, metadata, path, activation=self.activation, prior=self.prior
        )
