"""The start-up's heartbeat: a line per finished program and a status line while any is unfinished.

Stages are set by hand (``Heartbeat``) or by ``compile_programs`` on toy CPU programs; the expected lines
are written out from the stages set.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import pytest

from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compile_cache import QUICK_COMPILE
from bar_policy.training.startup.compiled import Program, compile_programs
from bar_policy.training.startup.compiler import Heartbeat
from bar_policy.training.startup.session import StartUp


def test_status_line_names_each_unfinished_program_its_stage_and_seconds():
    lines: list[str] = []
    beat = Heartbeat(lines.append, clock_origin=100.0, interval_s=3600.0)
    beat.set("reset", "compiling")
    beat.set("rollout", "tracing")
    beat.finished("init", "compiled in 0.5 s")
    # Stages set at about time.monotonic() = t; asked at t + 12: 12 s in each stage.
    now = beat._stages["rollout"].since + 12.0
    line = beat.status_line(now)
    assert line is not None
    head, rest = line.split(": ", 1)
    assert head == f"start-up {now - 100.0:.0f} s"
    assert rest.startswith("reset compiling (XLA) (12 s), rollout tracing (12 s)")
    assert rest.endswith("; done: init")
    assert lines == ["  program init: compiled in 0.5 s"]
    beat.finished("reset", "loaded from the compile cache in 0.2 s")
    beat.finished("rollout", "compiled in 30.0 s")
    assert beat.status_line() is None and beat.all_done()
    beat.close()


def test_unknown_stage_is_refused_with_the_valid_ones():
    beat = Heartbeat(print, clock_origin=0.0)
    with pytest.raises(ValueError, match="unknown stage 'linking'; valid: \\['queued', 'tracing'"):
        beat.set("x", "linking")


def test_status_lines_come_every_interval_until_every_program_is_done():
    lines: list[str] = []
    beat = Heartbeat(lines.append, clock_origin=time.monotonic(), interval_s=0.05)
    beat.set("rollout", "compiling")
    time.sleep(0.4)  # about 8 intervals; a loaded host may run fewer, never none in 0.4 s
    beat.finished("rollout", "compiled in 0.4 s")
    n = len(lines)
    time.sleep(0.2)  # the thread has stopped: no line after the program finished
    status = [s for s in lines if s.startswith("start-up ")]
    assert status and all("rollout compiling (XLA)" in s for s in status)
    assert lines[-1] == "  program rollout: compiled in 0.4 s" and len(lines) == n


def test_compile_programs_says_how_each_program_became_ready_with_quick_compile_options():
    lines: list[str] = []
    start = StartUp(timer=StartupTimer(), say=lines.append, compiler_options=dict(QUICK_COMPILE))
    programs = [
        Program("double", jax.jit(lambda a: 2.0 * a), (jnp.arange(5.0),)),
        Program("cube", jax.jit(lambda a: a**3), (jnp.arange(3.0),), background=True),
    ]
    compiled = compile_programs(programs, start)
    # The options reach XLA: the programs still compute 2 x and x^3 (0+2+4+6+8 = 20; 0+1+8 = 9).
    assert float(compiled["double"](jnp.arange(5.0)).sum()) == 20.0
    assert float(compiled["cube"](jnp.arange(3.0)).sum()) == 9.0
    done = sorted(s for s in lines if s.startswith("  program "))
    assert [s.split(":")[0] for s in done] == ["  program cube", "  program double"]
    # Each was compiled or served by the suite's persistent cache; either way with its seconds.
    assert all(" in " in s and s.endswith(" s") for s in done)
    assert all(("compiled in" in s) or ("loaded from the compile cache" in s) for s in done)
    compiled.close()
