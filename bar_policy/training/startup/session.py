"""A run's start-up before its programs exist: ``StartUp``, begun before jax's backend starts, opened later.

``StartUp.begin(cfg)`` is the first thing a run does (``training.run``): it sets the environment jax and
torch read when their backends start (``backend_env``), switches jax's persistent compile cache on
(``compile_cache.configure_compile_cache``), chooses the partitioner, connects ``jax.distributed`` and starts
seeding XLA's GPU autotune cache on a thread (``autotune``), so the seeding overlaps the env build.
``StartUp.open(cfg, record, env)``, once the run's record exists, waits for the seeding and opens the
executable cache (``executable_cache``, keyed by the record); it returns the lines that say what both did.
A trainer then hands its programs and the ``StartUp`` to ``compiled.compile_programs``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bar_policy.training.startup import breakdown as sb
from bar_policy.training.startup.breakdown import StartupTimer
from bar_policy.training.startup.compile_cache import (
    QUICK_COMPILE,
    QUICK_COMPILE_NOTE,
    configure_compile_cache,
    quiet_xla_alarms,
)
from bar_policy.training.startup.executable_cache import (
    ExecutableCache,
    executable_cache_for,
    executable_cache_line,
)

__all__ = ["StartUp"]


@dataclass
class StartUp:
    """What a run's start-up set up before its programs compile (``begin``, ``open``); see the module doc."""

    timer: StartupTimer = field(default_factory=StartupTimer)
    """The start-up breakdown, from the process start (or the ``run`` call)."""
    cache_dir: Path | None = None
    """jax's persistent compile cache (None: off)."""
    notes: list[str] = field(default_factory=list)
    """Lines for the run's header: the compile cache, the partitioner, the backend environment set."""
    executable_cache: ExecutableCache | None = None
    """Where the programs' executables are loaded from and stored (``open``; None: compiled every run)."""
    seeding: Future | None = None
    """The autotune seeding running on a thread (``autotune.seed_in_background``); ``open`` waits for it."""
    say: Callable[[str], None] | None = None
    """Prints a line (the run logger's ``print``, set once it exists): with it ``compiled.compile_programs``
    prints what the start-up is doing (``compiler.Heartbeat``); None: nothing is printed."""
    compiler_options: dict[str, Any] = field(default_factory=dict)
    """XLA options every program compiles with (``compile_cache.QUICK_COMPILE`` for ``quick_compile``)."""

    @classmethod
    def begin(cls, cfg: Any, started_at: float | None = None) -> StartUp:
        """Everything before jax's backend starts, in the order it must happen (the ``IMPORTS`` row).

        ``started_at``: ``time.monotonic()`` of the process start (the command line passes it); the
        breakdown then counts from there (its ``BEFORE_RUN`` row: interpreter, CLI, parsing).
        """
        from bar_policy.training.distributed import init_distributed
        from bar_policy.training.startup.autotune import seed_in_background
        from bar_policy.training.startup.backend_env import set_backend_env

        t0 = time.monotonic()
        timer = StartupTimer(t0 if started_at is None else started_at)
        if started_at is not None:
            timer.origin_name = "process start"
            timer.add(sb.BEFORE_RUN, t0 - started_at)
        with timer.phase(sb.IMPORTS):
            env_notes = set_backend_env(cfg)  # before anything starts jax's backend
            from bar_policy.training.parallel import choose_partitioner

            cache_dir = configure_compile_cache(cfg.compile_cache, cfg.compile_cache_dir)
            partitioner = choose_partitioner()
            with timer.phase(sb.DISTRIBUTED):
                init_distributed(cfg)
            seeding = seed_in_background(cache_dir, enabled=cfg.autotune_seed)  # waited for in ``open``
        cache_note = (
            f"compile cache: {cache_dir} (--no-compile-cache turns it off, --compile-cache-dir moves it)"
            if cache_dir
            else "compile cache: off"
        )
        partitioner_note = (
            f"partitioner: {partitioner} (JAX_USE_SHARDY_PARTITIONER in the environment chooses)"
        )
        notes = [cache_note, partitioner_note, *env_notes]
        options = dict(QUICK_COMPILE) if getattr(cfg, "quick_compile", False) else {}
        if options:
            notes += [QUICK_COMPILE_NOTE, quiet_xla_alarms()]
        return cls(timer=timer, cache_dir=cache_dir, notes=notes, seeding=seeding, compiler_options=options)

    def open(self, cfg: Any, record: dict[str, Any], env: Any) -> list[str]:
        """Wait for the autotune seeding and open the executable cache; returns the two lines saying so.

        ``record``: the run's config record (``provenance``, ``train``, ``env``, ``device``), which keys
        the executable cache with ``env``.
        """
        if self.seeding is not None:
            self.timer.autotune_seed = self.seeding.result()
        self.executable_cache = executable_cache_for(cfg, self.cache_dir, record, env)
        lines = [executable_cache_line(cfg, self.cache_dir, self.executable_cache)]
        if self.timer.autotune_seed is not None:
            lines.append(self.timer.autotune_seed.line())
        return lines
