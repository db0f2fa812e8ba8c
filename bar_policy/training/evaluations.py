"""A run's evaluations during training: their records in step order, the time to threshold, the best iterate.

Both trainers keep one ``Evaluations``. Each evaluation is first yielded to the run's logger
(``records.Evaluated``: it adds the time, writes and prints the figures), then kept here:

- ``records`` stays in step order: a record of an earlier step than one already kept (the step-0 evaluation
  run after training, ``eval.initial=end``) goes in before it, while ``metrics.jsonl`` has it where it ran,
  last;
- ``time_to_threshold_s`` is the time of the first evaluation at or above the success threshold, in the order
  they ran. Such a late step 0 does not count: its time says when it ran, not how long training took;
- the best keeper (``training.best.BestKeeper``) is offered it, and keeps a snapshot of the parameters when it
  ranks above every earlier one (the trainer's line then says so).
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from typing import Any

from bar_policy.training.best import BestIterate, BestKeeper
from bar_policy.training.records import Evaluated, Record, Said

__all__ = ["Evaluations"]


class Evaluations:
    """The evaluations of one run (module docstring).

    Args:
        first_step: env steps at the start of this run: evaluations at or before it are no best candidates
            (the untrained policy, a resumed run's past).
        task: the task whose ship gate ranks evaluations that carry quality figures (``best.score``).
        threshold: the success rate that counts as solved (0..1).
    """

    def __init__(self, first_step: int, task: str | None, threshold: float) -> None:
        self.records: list[dict[str, float]] = []
        """``{"step": ..., **figures}`` of every evaluation, in step order."""
        self.time_to_threshold_s: float | None = None
        """Seconds from the run's start to the first evaluation at or above ``threshold`` (None: not yet)."""
        self.threshold = threshold
        self.keeper = BestKeeper(first_step, task)

    @property
    def best(self) -> BestIterate | None:
        """The best evaluated iterate so far (None: no candidate evaluated)."""
        return self.keeper.best

    def record(
        self, step: int, metrics: dict[str, float], snapshot: Callable[[], Any], kept: str
    ) -> Generator[Record, Any, None]:
        """Yield the evaluation to the logger, keep what it answers (``add``); yield ``kept`` when it is best.

        ``snapshot``: a host copy of the evaluated parameters, taken only when they are kept.
        """
        recorded = yield Evaluated(step, metrics)
        if self.add(step, recorded, snapshot):
            yield Said((kept,))

    def add(self, step: int, metrics: dict[str, float], snapshot: Callable[[], Any]) -> bool:
        """Keep an evaluation as recorded (``time_s`` included); returns whether it is the best so far."""
        later = next((i for i, e in enumerate(self.records) if e["step"] > step), None)
        self.records.insert(len(self.records) if later is None else later, {"step": step, **metrics})
        if later is None and self.time_to_threshold_s is None and metrics["success_rate"] >= self.threshold:
            self.time_to_threshold_s = metrics["time_s"]
        return self.keeper.offer(step, metrics, snapshot)
