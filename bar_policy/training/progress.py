"""Run directory, progress lines, TensorBoard / wandb, a JSON-lines metric log and the checkpoints.

Every metric record goes to three places: ``<run>/metrics.jsonl`` (one JSON object per line, the source of
``docs/training_curve.png``), the run's writer (``--logger``: TensorBoard event files in ``<run>/tb``, also
wandb, or none; ``training.writers``), under the tags of ``training.log_tags``, and, for the main numbers,
one terminal line::

    [ 37%] 14.7M/40.0M steps | 301k steps/s | reward 312.4 | success 91.2% (eval 93.0%) | 1m04s, ETA 1m23s

The trainers never call it: they yield records (``training.records``), and ``RunLogger.follow`` reports each
as it comes, the one place a run's figures are printed and written.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Generator, Sequence
from pathlib import Path
from typing import Any, TextIO, TypeVar

from bar_policy.training.log_tags import tag
from bar_policy.training.records import (
    Epoch,
    Evaluated,
    Final,
    NotApplied,
    Record,
    Resumed,
    SaveCheckpoint,
    ScalarWriter,
)
from bar_policy.training.writers import check_logger, make_writer

__all__ = ["RunLogger", "format_duration", "format_eval", "format_steps", "next_would_overrun"]

R = TypeVar("R")


def format_steps(n: float) -> str:
    """``1234567 -> '1.23M'``."""
    for div, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(n) >= div:
            return f"{n / div:.3g}{unit}"
    return f"{n:.0f}"


def next_would_overrun(elapsed_s: float, next_s: float, budget_s: float) -> bool:
    """Whether a next step expected to take ``next_s`` would end past a wall-clock budget, s.

    The trainers stop *before* an epoch that would overrun ``max_minutes`` (its expected length: the last
    epoch's, plus the last evaluation's when one is due, plus one more while the step-0 evaluation waits
    for the end of training, ``eval.initial=end``), so the budget bounds the run instead of being
    overshot by up to one epoch; ``budget_s <= 0`` means no budget.
    """
    return budget_s > 0 and elapsed_s + next_s > budget_s


def format_eval(metrics: dict[str, float]) -> str:
    """An evaluation's figures on one line.

    Success, episode reward, final distance (cm) when the task has one, then every other figure (``time_s``
    and ``episodes`` left out: the line's head says them).
    """
    text = f"success {100 * metrics['success_rate']:.1f}%, episode reward {metrics['episode_reward']:.2f}"
    if "final_distance" in metrics:
        text += f", final distance {100 * metrics['final_distance']:.2f} cm"
    skip = ("success_rate", "episode_reward", "episode_reward_std", "final_distance", "time_s", "episodes")
    for k, v in metrics.items():
        if k not in skip:
            text += f", {k} {v:.4g}"
    return text


def format_duration(seconds: float) -> str:
    """``83.2 -> '1m23s'``; '?' for unknown."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    s = round(seconds)
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class RunLogger:
    """Writes one run's metrics (only process 0 of a multi-host job should own one that is enabled).

    Args:
        run_dir: the run directory (created).
        total_steps: target env steps (for percentages and ETA).
        enabled: False makes every method a no-op (non-zero processes).
        stream: where progress lines go (default stdout).
        logger: ``--logger``: ``tensorboard``, ``wandb`` or ``none`` (``training.writers``).
        wandb_project: the wandb project (``logger="wandb"``).

    The writer is made at the first scalar, unless a backend hands its own over first (``attach_writer``:
    the rsl-rl backend's is made by rsl-rl's runner logger).
    """

    def __init__(
        self,
        run_dir: str | Path,
        total_steps: int,
        *,
        enabled: bool = True,
        stream: TextIO | None = None,
        logger: str = "tensorboard",
        wandb_project: str = "bar_policy",
    ) -> None:
        check_logger(logger)
        self.run_dir = Path(run_dir)
        self.total_steps = int(total_steps)
        self.enabled = enabled
        self.stream = stream or sys.stdout
        self.logger = logger
        self.wandb_project = wandb_project
        self.t0 = time.monotonic()
        self._tb: Any = None
        self._jsonl: TextIO | None = None
        self.last_eval: dict[str, float] = {}
        self.evaluated_on = ""
        """What the evaluations run on, for their lines' heads (``run``: ``held-out set`` or '')."""
        self.config_record: dict[str, Any] | None = None
        """The run's record, which checkpoint sidecars carry (``run_dir.open_run`` sets it)."""
        if enabled:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            self._jsonl = (self.run_dir / "metrics.jsonl").open("a")

    @property
    def tb_dir(self) -> Path:
        """The event files' directory, ``<run>/tb``."""
        return self.run_dir / "tb"

    @property
    def writes_scalars(self) -> bool:
        """Whether this process writes scalars (enabled, and a logger other than ``none``)."""
        return self.enabled and self.logger != "none"

    def attach_writer(self, writer: Any) -> None:
        """Write the scalars through ``writer`` (``add_scalar(tag, value, step)``, ``flush``, ``close``).

        The rsl-rl backend hands over the writer rsl-rl's runner logger made (same directory, same tags).
        A writer this logger had already made is closed (its event file stays; TensorBoard reads both).
        """
        if self._tb is not None and self._tb is not writer:
            self._tb.close()
        self._tb = writer

    def _writer(self) -> Any:
        if self._tb is None and self.writes_scalars:
            self._tb = make_writer(
                self.logger, self.tb_dir, project=self.wandb_project, run_name=self.run_dir.name
            )
        return self._tb

    def elapsed(self) -> float:
        """Seconds since the logger was created."""
        return time.monotonic() - self.t0

    def log(self, step: int, metrics: dict[str, float], *, kind: str) -> None:
        """Record ``metrics`` at env step ``step``; ``kind`` is ``train``, ``eval`` or ``final``."""
        if not self.enabled:
            return
        clean = {k: float(v) for k, v in metrics.items() if _finite_number(v)}
        record = {"kind": kind, "step": int(step), "time_s": round(self.elapsed(), 3), **clean}
        assert self._jsonl is not None
        self._jsonl.write(json.dumps(record) + "\n")
        self._jsonl.flush()
        writer = self._writer()
        if writer is not None:
            for k, v in clean.items():
                writer.add_scalar(tag(kind, k), v, int(step))
            writer.flush()
        if kind == "eval":
            self.last_eval = clean

    def opened(self, provenance: dict[str, Any], header: Sequence[str]) -> None:
        """A run's first records: its ``provenance`` as a ``metrics.jsonl`` line, then its header printed."""
        self.note("provenance", {"provenance": provenance})
        for line in header:
            self.print(line)

    def note(self, kind: str, payload: dict[str, Any]) -> None:
        """One non-metric JSON line in ``metrics.jsonl``: ``{"kind": kind, "time_s": ..., **payload}``.

        For records such as the run's provenance (strings, nested objects); TensorBoard gets nothing.
        """
        if not self.enabled:
            return
        assert self._jsonl is not None
        self._jsonl.write(json.dumps({"kind": kind, "time_s": round(self.elapsed(), 3), **payload}) + "\n")
        self._jsonl.flush()

    def follow(self, trainer: Generator[Record, Any, R]) -> R:
        """Report every record a trainer yields, as it comes, and send back its answer; returns its result.

        ``trainer``: a trainer's generator (``training.records``); its return value is the result.
        """
        answer: Any = None
        while True:
            try:
                record = trainer.send(answer)
            except StopIteration as end:
                return end.value
            answer = self.report(record)

    def report(self, record: Record) -> Any:
        """Print, write and answer one record (``training.records``).

        An ``Epoch`` is answered by ``epoch_end``'s budget answer, an ``Evaluated`` by ``evaluated``'s
        record; the others by None.
        """
        if isinstance(record, Epoch):
            return self.epoch_end(
                record.step,
                record.metrics,
                next_s=record.next_s,
                budget_s=record.budget_s,
                line=record.line,
                line_due=record.line_due,
                notes=record.notes,
            )
        if isinstance(record, Evaluated):
            return self.evaluated(record.step, record.metrics)
        if isinstance(record, Final):
            self.log(record.step, record.metrics, kind="final")
            self.print(record.line)
        elif isinstance(record, Resumed):
            self.resumed(record.path, record.env_steps, record.iteration, list(record.changes))
        elif isinstance(record, NotApplied):
            self.not_applied(list(record.settings))
        elif isinstance(record, ScalarWriter):
            self.attach_writer(record.writer)
        elif isinstance(record, SaveCheckpoint):
            self.save_checkpoint(record.state, record.env_steps, record.iteration)
        else:
            for line in record.lines:
                self.print(line)
            if record.note:
                self.note(record.note, dict(record.payload))
        return None

    def evaluated(self, step: int, metrics: dict[str, float]) -> dict[str, float]:
        """Log and print one evaluation; returns it as recorded, ``time_s`` (seconds since ``t0``) added.

        Args:
            step: env steps so far (or 0, for the untrained policy).
            metrics: the evaluation (``success_rate``, ``episode_reward``, optionally ``final_distance``, m,
                and the task's other ratios); ``time_s`` is added in place.
        """
        metrics["time_s"] = self.elapsed()
        self.log(step, metrics, kind="eval")
        on = f", {self.evaluated_on}" if self.evaluated_on else ""
        head = f"initial evaluation (the untrained policy{on})" if step == 0 else f"eval @ {step:,} steps"
        head += f" ({self.evaluated_on})" if step and self.evaluated_on else ""
        self.print(f"  {head}: {format_eval(metrics)}")
        return metrics

    def epoch_end(
        self,
        step: int,
        metrics: dict[str, float],
        *,
        next_s: float,
        budget_s: float,
        line: Callable[[], tuple[float, dict[str, float]]] | None = None,
        line_due: bool = True,
        notes: Sequence[str] = (),
    ) -> bool:
        """Record one epoch's training figures, print its progress line, and check the wall-clock budget.

        A trainer's ``records.Epoch``, at each epoch end: ``metrics`` (with ``sps``, env steps/s) logged as
        ``train`` at env step ``step``; then whether a next epoch expected to take ``next_s`` s would end
        past ``budget_s`` s (``next_would_overrun``); then the progress line.

        Args:
            step: env steps so far.
            metrics: the epoch's training figures, ``sps`` among them.
            next_s: the next epoch's expected length, s (with the evaluations due in it).
            budget_s: the wall-clock budget, s (``<= 0``: none).
            line: the progress line's ``(steps/s, figures)``, called only when a line is printed (rsl-rl's
                covers the iterations since its previous line); default: ``(metrics["sps"], metrics)``.
            line_due: whether this epoch prints a line (rsl-rl: every few iterations); the last one before
                the budget runs out always does.
            notes: lines said first, before the figures (rsl-rl: the torch->jax copies, when there are new).

        Returns:
            Whether the next epoch would overrun the budget (this process's answer).
        """
        for text in notes:
            self.print(text)
        self.log(step, metrics, kind="train")
        over = next_would_overrun(self.elapsed(), next_s, budget_s)
        if line_due or over:
            self.progress(step, *((metrics["sps"], metrics) if line is None else line()))
        return over

    def progress(self, step: int, sps: float, metrics: dict[str, float]) -> None:
        """Print the progress line for env step ``step`` at ``sps`` env steps/s."""
        if not self.enabled:
            return
        frac = min(step / max(self.total_steps, 1), 1.0)
        eta = (self.total_steps - step) / sps if sps > 0 else math.inf
        parts = [
            f"[{100 * frac:3.0f}%] {format_steps(step)}/{format_steps(self.total_steps)} steps",
            f"{format_steps(sps)} steps/s",
        ]
        if "episode_reward" in metrics:
            parts.append(f"reward {metrics['episode_reward']:.2f}")
        if "success_rate" in metrics:
            ev = self.last_eval.get("success_rate")
            tail = f" (eval {100 * ev:.1f}%)" if ev is not None else ""
            parts.append(f"success {100 * metrics['success_rate']:.1f}%{tail}")
        parts.append(f"{format_duration(self.elapsed())}, ETA {format_duration(eta)}")
        self.print(" | ".join(parts))

    def print(self, text: str) -> None:
        """A line on the terminal (flushed)."""
        if self.enabled:
            print(text, file=self.stream, flush=True)

    def resumed(self, path: str | Path, env_steps: int, iteration: int, changes: list[str]) -> None:
        """Say which checkpoint a run resumed, where, and the settings that differ from the resumed run's.

        ``changes``: ``training.checkpoint.resume_changes``'s lines (none when nothing differs).
        """
        self.print(f"resumed {path} at {env_steps} env steps (iteration {iteration})")
        for line in changes:
            self.print(line)

    def not_applied(self, settings: list[str]) -> None:
        """Print each setting the backend runs without, and record them as one ``not_applied`` line."""
        for line in settings:
            self.print(line)
        if settings:
            self.note("not_applied", {"settings": settings})

    def save_checkpoint(self, state: Any, env_steps: int, iteration: int) -> None:
        """Write a checkpoint into ``<run>/checkpoints``, its sidecar carrying ``config_record``."""
        from bar_policy.training.checkpoint import save_checkpoint  # flax's serialization

        if self.enabled:
            save_checkpoint(
                self.run_dir / "checkpoints",
                state,
                env_steps=env_steps,
                iteration=iteration,
                extra=self.config_record,
            )

    def close(self) -> None:
        """Flush and close the files."""
        if self._jsonl is not None:
            self._jsonl.close()
            self._jsonl = None
        if self._tb is not None:
            self._tb.close()
            stop = getattr(self._tb, "stop", None)  # a wandb writer: finish its run
            if stop is not None:
                stop()
            self._tb = None


def _finite_number(v: Any) -> bool:
    try:
        return math.isfinite(float(v))
    except (TypeError, ValueError):
        return False
