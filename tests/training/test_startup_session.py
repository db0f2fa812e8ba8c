"""The start-up's one call: ``compile_programs`` in order, and ``CompiledPrograms`` ending the start-up.

Toy programs on the CPU backend; the expected values are worked out by hand in each test.
"""

from __future__ import annotations

import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bar_policy.training.records import Said
from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compiled import Program, compile_programs
from bar_policy.training.startup.session import StartUp


class _Logger:
    """What the run's logger makes of ``CompiledPrograms.report``'s record: printed lines and notes."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.notes: list[tuple[str, dict[str, Any]]] = []

    def report(self, record: Said | None) -> None:
        if record is None:  # not reported (yet)
            return
        self.lines.extend(record.lines)
        if record.note:
            self.notes.append((record.note, dict(record.payload)))


def _toy(timer: StartupTimer) -> Any:
    """``double(x) = 2 x`` and ``total(y) = sum(y)``, the second traced on the first's ``out_info``."""

    def total_args(out: Any) -> tuple:
        o = out["double"]
        return (jax.ShapeDtypeStruct(o.shape, o.dtype),)

    programs = [
        Program("double", jax.jit(lambda a: 2.0 * a), (jnp.arange(6.0),)),
        Program("total", jax.jit(lambda a: a.sum()), total_args),
        Program("cube", jax.jit(lambda a: a**3), (jnp.arange(3.0),), background=True),
    ]
    return compile_programs(programs, StartUp(timer=timer))


def test_programs_compile_in_order_each_on_the_outputs_of_those_before():
    timer = StartupTimer()
    compiled = _toy(timer)
    x = jnp.arange(6.0)
    # 2 * (0 + 1 + ... + 5) = 30; cube of 0, 1, 2 = 0, 1, 8.
    assert float(compiled["total"](compiled["double"](x))) == 30.0
    np.testing.assert_array_equal(np.asarray(compiled["cube"](jnp.arange(3.0))), [0.0, 1.0, 8.0])
    assert list(timer.programs) == ["double", "total", "cube"]
    assert [p.thread for p in timer.programs.values()] == ["main", "main", "worker"]
    assert compiled.ready("double", "total", "cube")
    compiled.close()


def _epoch(compiled: Any, seconds: float, step: int, **kw: Any) -> Any:
    """``compiled.epoch_ended`` for an epoch that ended now, the evaluation's program being ``cube``."""
    return compiled.epoch_ended(seconds, ended_at=time.monotonic(), step=step, eval_programs=("cube",), **kw)


def test_the_start_up_ends_with_the_first_epoch_and_is_reported_once():
    timer = StartupTimer(origin=time.monotonic() - 1.0)
    compiled, logger = _toy(timer), _Logger()
    logger.report(_epoch(compiled, 0.5, 4096, step0_s=None, step0_waiting=False, eval_due=True))
    # No step-0 evaluation waits: not a start-up row.
    logger.report(_epoch(compiled, 0.25, 8192, step0_s=None, step0_waiting=False, eval_due=True))
    assert timer.phases[sb.FIRST_EPOCH] == 0.5 and sb.MORE_EPOCHS not in timer.phases
    ((kind, rec),) = logger.notes
    assert kind == "startup" and rec["step"] == 4096 and rec["until"] == sb.UNTIL_EPOCH
    assert rec["phases"][sb.FIRST_EVAL] == 0.0 and set(rec["programs"]) == {"double", "total", "cube"}
    # At least the 1 s before the timer's origin was made; the first epoch ended after that.
    assert rec["total_s"] >= rec["first_epoch_end_s"] >= 1.0
    assert logger.lines[0].startswith("start-up: ") and "end of the first epoch" in logger.lines[0]
    compiled.close()


def test_a_step0_evaluation_first_ends_the_start_up_after_it():
    """eval.initial=start: epochs while the step-0 evaluation waits count, and the start-up ends with it."""
    timer = StartupTimer()
    compiled, logger = _toy(timer), _Logger()
    logger.report(_epoch(compiled, 0.5, 4096, step0_s=None, step0_waiting=True, eval_due=False))
    assert not compiled.reported  # the step-0 evaluation has not run: the start-up goes on
    t = time.monotonic()
    time.sleep(0.05)  # the step-0 evaluation, after the second epoch
    compiled["cube"]  # the evaluation's program is ready: the report needs no evaluation due
    step0_s = time.monotonic() - t
    logger.report(_epoch(compiled, 0.25, 8192, step0_s=step0_s, step0_waiting=False, eval_due=False))
    ((_, rec),) = logger.notes
    assert rec["until"] == sb.UNTIL_EVAL and rec["step"] == 8192
    assert rec["phases"][sb.FIRST_EPOCH] == 0.5 and rec["phases"][sb.MORE_EPOCHS] == 0.25
    assert rec["phases"][sb.FIRST_EVAL] >= 0.05  # the sleep, at least
    before = timer.phases[sb.FIRST_EVAL]
    # After the report, an evaluation is no start-up row.
    logger.report(_epoch(compiled, 0.25, 12288, step0_s=0.01, step0_waiting=False, eval_due=False))
    assert timer.phases[sb.FIRST_EVAL] == before
    compiled.close()
