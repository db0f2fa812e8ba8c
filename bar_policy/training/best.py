"""The best iterate of a run: the evaluated parameters that scored highest, kept beside the last ones.

PPO is not monotone on hard tasks. The shipped tracker's run (``docs/tracking.md``) reached 92 % eval
success at 57.7M env steps and ended at 36 %; only the last iterate was exported, so the better policy was
lost. A run now keeps a host copy of the parameters at each evaluation that beats every earlier one, and at
the end, when that iterate is not the last one, evaluates it again on the final evaluation's seeds and
exports it as ``<policy>_best.onnx`` next to ``policy.onnx`` (``training.summary.finish_best``, a step of
how a run ends).

Order: when the evaluation measured safety and smoothness (the MJX evaluation's ``quality/*`` figures, on
held-out data), the ship gate's ``score`` (``bar_policy.quality.gate``): the least total excess beyond the
gate's thresholds (completion, torque caps, chatter, tracking errors, each relative to its threshold), then
accuracy. Otherwise (an
evaluation without them) a higher ``success_rate`` wins, then a higher ``episode_reward`` (ties at 100 %
success are common on reach). Only parameters trained in this run count: the evaluation at step 0
(untrained parameters) and evaluations before a resume are not candidates.

The best of N noisy evaluations is an optimistic estimate of that iterate (selection bias). The final
evaluation of the best iterate uses fresh seeds, the same ones as the last iterate's, so the two final
figures in ``final_eval.json`` are a fair, paired comparison; that is the figure to choose by.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import bar_policy.tasks.registry  # noqa: F401 - registers every task's gate
from bar_policy.quality import gate

__all__ = [
    "BestIterate",
    "BestKeeper",
    "best_onnx_path",
    "held_out_report",
    "is_better",
    "score",
]


def held_out_report(metrics: Mapping[str, float]) -> dict[str, Any]:
    """An evaluation's figures in the ship gate's report form (``bar_policy.quality.gate``).

    ``quality/<key>`` become the ``quality`` summary; ``joint_error_rad`` and ``fingertip_error_cm``
    (tracking) stay; ``success_rate`` becomes ``success_pct``; the piano's ``recall_black`` / ``recall_white``
    fill ``recall_pct``.
    """
    report: dict[str, Any] = {
        "quality": {k.split("/", 1)[1]: v for k, v in metrics.items() if k.startswith("quality/")},
        "success_pct": 100.0 * float(metrics["success_rate"]),
    }
    for k in ("joint_error_rad", "fingertip_error_cm"):
        if k in metrics:
            report[k] = metrics[k]
    if "recall_black" in metrics and "recall_white" in metrics:  # the piano's per-colour recall
        # The MJX evaluation plays the training bank (random songs of seed 0 and the library): it stands in
        # for both of the gate's song sets (``tasks/piano/gate.py``), so an iterate that skips black keys
        # ranks below one that plays them.
        report["recall_pct"] = {
            f"{group} {colour} keys": 100.0 * float(metrics[f"recall_{colour}"])
            for group in ("held-out", "random")
            for colour in ("black", "white")
        }
    return report


def score(metrics: Mapping[str, float], task: str | None = None) -> tuple[float, ...]:
    """Ranking key of an evaluation (higher is better; NaN counts as the worst value).

    With ``task`` and the evaluation's ``quality/*`` figures: the gate's score of ``held_out_report``;
    otherwise ``(success_rate, episode_reward)``.
    """
    if task is not None and "quality/completion_pct" in metrics:
        report = held_out_report(metrics)
        return gate.score(task, report)

    def clean(x: float) -> float:
        return -math.inf if math.isnan(x) else x

    return clean(float(metrics["success_rate"])), clean(float(metrics["episode_reward"]))


def is_better(new: Mapping[str, float], old: Mapping[str, float] | None, task: str | None = None) -> bool:
    """True when evaluation ``new`` ranks strictly above ``old`` (any evaluation beats none)."""
    return old is None or score(new, task) > score(old, task)


@dataclass(frozen=True, kw_only=True)
class BestIterate:
    """The highest-ranked evaluated parameters of a run."""

    step: int
    """Env steps trained when the parameters were evaluated."""
    metrics: dict[str, float]
    """The evaluation during training that selected them (its seeds, not the final evaluation's)."""
    params: Any
    """Host copy of the parameters, in the backend's layout (brax: ``(normalizer, policy, value)``; rsl-rl:
    a copy of the actor module)."""


class BestKeeper:
    """Offer each evaluation; keeps the best one with a snapshot of its parameters.

    ``snapshot`` is called only for an evaluation that beats the kept one, so a run pays one host copy
    of a small network per improvement, not per evaluation.
    """

    def __init__(self, first_step: int, task: str | None = None) -> None:
        """Keep the best evaluation after ``first_step``.

        ``first_step``: env steps at the start of this run (evaluations at or before it are skipped);
        ``task``: the task whose ship gate ranks evaluations that carry quality figures (``score``).
        """
        self.first_step = int(first_step)
        self.task = task
        self.best: BestIterate | None = None
        self._best_score: tuple[float, ...] = ()
        """``score`` of ``best``'s metrics, taken when it was kept (the ranking ``is_better`` applies)."""

    def offer(self, step: int, metrics: Mapping[str, float], snapshot: Callable[[], Any]) -> bool:
        """Keep ``(step, metrics, snapshot())`` if it is a candidate and ranks above the kept one.

        The kept evaluation's score is taken once, when it is kept; each offer scores only the new one.
        """
        if step <= self.first_step:
            return False
        new = score(metrics, self.task)
        if self.best is not None and not new > self._best_score:
            return False
        self.best = BestIterate(step=int(step), metrics=dict(metrics), params=snapshot())
        self._best_score = new
        return True


def best_onnx_path(onnx_path: str | Path) -> Path:
    """Where the best iterate is exported: ``policy.onnx`` -> ``policy_best.onnx`` (same folder)."""
    p = Path(onnx_path)
    return p.with_name(f"{p.stem}_best{p.suffix or '.onnx'}")
