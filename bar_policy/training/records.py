"""What a trainer tells its run while it trains: records, reported as they come by the run's logger.

The trainers (``brax.ppo.train_brax``, ``rsl_rl.backend.train_rsl_rl``) are generators: each yields these
records as its training produces them and returns its result (and so is the end of a run,
``summary.finish_run``: the final evaluation, the summary table). ``training.run`` hands the generator to
``RunLogger.follow``, the one place that prints, writes ``metrics.jsonl`` and the scalars, so a trainer never
holds the logger and its loop reads as its algorithm (rollout, update, evaluate).

Two records are answered, through the generator's ``yield`` expression (``RunLogger.report``): an ``Epoch`` by
whether the next epoch would end past the wall-clock budget (the logger's clock is the run's), an
``Evaluated`` by the evaluation as recorded, its ``time_s`` added. Every other record is answered None.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "Epoch",
    "Evaluated",
    "Final",
    "NotApplied",
    "Record",
    "Resumed",
    "Said",
    "SaveCheckpoint",
    "ScalarWriter",
]


@dataclass(frozen=True)
class Said:
    """Lines to print, and with ``note`` one non-metric ``metrics.jsonl`` line (``RunLogger.note``)."""

    lines: tuple[str, ...] = ()
    """Printed in order (process 0 only, as every line)."""
    note: str = ""
    """The ``kind`` of the ``metrics.jsonl`` line (``startup``, ...); '' writes none."""
    payload: Mapping[str, Any] = field(default_factory=dict)
    """That line's fields."""


@dataclass(frozen=True)
class Epoch:
    """One training epoch's figures (rsl-rl: one iteration's), at its end (``RunLogger.epoch_end``).

    Answered by whether a next epoch expected to take ``next_s`` would end past ``budget_s``.
    """

    step: int
    """Env steps so far."""
    metrics: dict[str, float]
    """The epoch's training figures (``sps`` among them), logged as ``train``."""
    next_s: float
    """The next epoch's expected length, s (with the evaluations due in it)."""
    budget_s: float
    """The wall-clock budget, s (``<= 0``: none)."""
    line: Callable[[], tuple[float, dict[str, float]]] | None = None
    """The progress line's ``(steps/s, figures)``, called only when a line is printed; None: the epoch's."""
    line_due: bool = True
    """Whether this epoch prints a progress line (the last one before the budget runs out always does)."""
    notes: tuple[str, ...] = ()
    """Lines said first, before the figures."""


@dataclass(frozen=True)
class Evaluated:
    """One evaluation's figures at env step ``step`` (0: the untrained policy), before it is recorded.

    Answered by the figures as recorded: ``metrics`` with ``time_s``, seconds since the run's start.
    """

    step: int
    metrics: dict[str, float]


@dataclass(frozen=True)
class Final:
    """The run's final evaluation at env step ``step``: logged as ``final``, and its ``line`` printed."""

    step: int
    metrics: dict[str, float]
    line: str


@dataclass(frozen=True)
class Resumed:
    """A run resumed ``path`` at ``env_steps`` (``iteration``); ``changes``: the settings that differ."""

    path: str | Path
    env_steps: int
    iteration: int
    changes: tuple[str, ...] = ()
    """``training.checkpoint.resume_changes``'s lines (none when nothing differs)."""


@dataclass(frozen=True)
class SaveCheckpoint:
    """A checkpoint to write (``checkpoint.save_checkpoint``, into ``<run>/checkpoints``, process 0 only).

    Its sidecar carries the run's record. ``state``: a tree of host arrays (brax: the training state; rsl-rl:
    the actor's, critic's and optimizer's state dicts and the learning rate).
    """

    state: Any
    env_steps: int
    iteration: int


@dataclass(frozen=True)
class NotApplied:
    """The settings a backend runs without (one line each), said and recorded as ``not_applied``."""

    settings: tuple[str, ...]


@dataclass(frozen=True)
class ScalarWriter:
    """The writer the run's scalars go through from now on (``RunLogger.attach_writer``).

    The rsl-rl backend's, made by rsl-rl's runner logger in the run's ``tb/`` (same tags as the logger's own).
    """

    writer: Any
    """``add_scalar(tag, value, step)``, ``flush``, ``close``."""


Record = Said | Epoch | Evaluated | Final | Resumed | SaveCheckpoint | NotApplied | ScalarWriter
"""Everything a trainer yields."""
