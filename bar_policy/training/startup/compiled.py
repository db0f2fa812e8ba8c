"""A trainer's programs, compiled: its one start-up call in, ``CompiledPrograms`` out, and the start-up's end.

A trainer calls ``compile_programs(programs, start)`` once: its jitted programs (``Program``, in the
order to submit them) and the run's ``session.StartUp`` in, ``CompiledPrograms`` out. Each is traced and
lowered on the calling thread (or a worker) and compiled on worker threads, or loaded from the executable
cache (``compiler.Compiler``); every stage is timed into the start-up breakdown (``breakdown``). The
trainer's loop only says when an epoch ends and what the step-0 evaluation took (``epoch_ended``, once per
epoch): the start-up's end, and the breakdown once no program is still compiling (a record the trainer
yields to the run's logger, which prints and records it: ``training.records``), are decided here, alike for
both trainers.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bar_policy.training.records import Said
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.compiler import Compiler, CompileStats
from bar_policy.training.startup.session import StartUp

__all__ = ["CompiledPrograms", "Program", "compile_programs"]


@dataclass(frozen=True)
class Program:
    """One jitted program of a trainer, as ``compile_programs`` submits it."""

    name: str
    """Its name in the breakdown and the executable cache's key (``rollout``, ``train step``, ...)."""
    jitted: Callable[..., Any]
    """The ``jax.jit`` function."""
    args: tuple[Any, ...] | Callable[[Mapping[str, Any]], tuple[Any, ...]]
    """Its arguments (arrays or ``ShapeDtypeStruct``s), or a function of the ``out_info`` of the programs
    submitted before it, by name (the rollout's envs are the reset's output)."""
    background: bool = False
    """Traced on a worker too (nothing waits on it soon: the evaluation)."""
    load_in_background: bool = False
    """When stored in the executable cache, loaded on a worker (its output is not read by what follows)."""


def compile_programs(programs: Sequence[Program], start: StartUp | None = None) -> CompiledPrograms:
    """Submit ``programs`` in order: each traced and lowered (or loaded) now, compiled on worker threads.

    The one start-up call of a trainer. Trace order is submission order: put the programs the start waits
    on first, the longest compile early, and those traced on a worker (``background``) last, since tracing
    holds the GIL. ``start``: the run's ``StartUp`` (its breakdown and executable cache); None: a fresh
    breakdown, no executable cache.
    """
    compiled = CompiledPrograms(start or StartUp())
    out: dict[str, Any] = {}
    for p in programs:
        args = p.args(out) if callable(p.args) else p.args
        submitted = compiled.compiler.submit(
            p.name, p.jitted, *args, background=p.background, load_in_background=p.load_in_background
        )
        if submitted is not None:
            out[p.name] = submitted.out_info
    return compiled


class CompiledPrograms:
    """A trainer's programs, compiling or compiled (``compile_programs``), and the end of its start-up.

    ``programs[name]`` is the executable (waits for its compile or load; re-raises its error). The loop
    reports each epoch and the step-0 evaluation after it here (``epoch_ended``); the start-up ends with the
    first epoch, or with the step-0 evaluation when it runs first (``eval.initial=start``), and its
    breakdown is reported once the evaluation's programs are ready, before the first evaluation at the
    latest.
    """

    def __init__(self, start: StartUp) -> None:
        """Programs compiled for ``start``: its breakdown, its executable cache, its lines, its options."""
        self.timer = start.timer
        self.compiler = Compiler(
            start.timer,
            executable_cache=start.executable_cache,
            say=start.say,
            compiler_options=start.compiler_options,
        )
        self._stats0 = CompileStats.get().snapshot()
        self._epochs = 0
        self._first_epoch_end = 0.0
        self._end_s: float | None = None  # when the start-up ended (its report may come later)
        self._until = sb.UNTIL_EPOCH
        self._step0_ran = False
        self.reported = False
        """Whether the start-up breakdown was printed and recorded."""

    def __getitem__(self, name: str) -> Any:
        return self.compiler.get(name)

    def ready(self, *names: str) -> bool:
        """Whether every program of ``names`` finished compiling (or loading)."""
        return all(self.compiler.done(n) for n in names)

    def confirm(self) -> None:
        """Every program loaded from the executable cache ran: none is a suspect of a crash."""
        self.compiler.confirm()

    def epoch_ended(
        self,
        seconds: float,
        *,
        ended_at: float,
        step: int,
        step0_s: float | None,
        step0_waiting: bool,
        eval_due: bool,
        eval_programs: Sequence[str],
    ) -> Said | None:
        """A training epoch (rsl-rl: an iteration) of ``seconds`` ended at ``ended_at`` (``time.monotonic``).

        While the start-up lasts the epoch is timed into the breakdown: the first is ``FIRST_EPOCH``; later
        ones count (``MORE_EPOCHS``) while the step-0 evaluation waited for its program (``eval.initial=
        start``); that evaluation, when it ran after this epoch, took ``step0_s`` (``FIRST_EVAL``; None: it
        did not run). The start-up ends once no step-0 evaluation waits (``step0_waiting``: it still does).

        Returns the start-up's report (``report``) once it ended and ``eval_programs`` are ready, or an
        evaluation is due at the latest (it would wait for its programs anyway), so that no row of the
        breakdown is a program still compiling on a worker; None otherwise.
        """
        self._epochs += 1
        if self._epochs == 1:
            self.timer.add(sb.FIRST_EPOCH, seconds)
            self._first_epoch_end = ended_at - self.timer.origin
        elif step0_waiting or step0_s is not None:
            self.timer.add(sb.MORE_EPOCHS, seconds)
        if step0_s is not None and not self.reported:
            self.timer.add(sb.FIRST_EVAL, step0_s)
            self._step0_ran = True
        if self._end_s is None and not step0_waiting:
            self._end_s = self.timer.elapsed()
            self._until = sb.UNTIL_EVAL if self._step0_ran else sb.UNTIL_EPOCH
        if not self.reported and self._end_s is not None and (eval_due or self.ready(*eval_programs)):
            for name in eval_programs:
                self[name]
            return self.report(step)
        return None

    def report(self, step: int) -> Said | None:
        """The start-up breakdown, for the run's logger to print and record (``startup``).

        Once: None when already reported, or before an epoch ran.
        """
        if self.reported or not self._epochs:
            return None
        self.reported = True
        stats1 = CompileStats.get().snapshot()
        compiles = {k: stats1[k] - self._stats0[k] for k in stats1}
        rec = self.timer.finish(self._first_epoch_end, compiles, total_s=self._end_s, until=self._until)
        return Said(tuple(self.timer.lines(rec)), note="startup", payload={"step": step, **rec})

    def close(self) -> None:
        """Release the worker threads."""
        self.compiler.close()
