"""The start-up breakdown: where the seconds before training runs went, by name, printed and recorded.

Two views of the same start:

- **Main-thread phases** (``PHASES``), in order and exclusive (``bar_policy._phases.PhaseClock``): from the
  process start (or the ``run()`` call) to the end of the start-up, through imports, the model build, the
  env construction, tracing and lowering, the wait for the compiles, the first epoch and, with
  ``eval.initial=start``, the step-0 evaluation. The start-up ends with that evaluation, or else (``end``,
  ``off``, a resume) with the first epoch, and then the evaluation rows are left out of the printed table
  (``UNTIL_EPOCH``). They never overlap, so they add up to at most the wall time around them; what no
  phase claims is the ``OTHER`` row, so the rows add up to the total.
- **Programs**: each compiled program's trace, lower and compile (or persistent-cache load) seconds, with
  its cache outcome. The compiles run on worker threads, overlapping each other and the phases above.

The record also says what seeding XLA's autotune cache did (``startup.autotune``, one ``autotune seed: ...``
line in the table), since a cold GPU compile is about 30 s shorter with it.

The breakdown counts from the process start when the command line passes it (``process_uptime``), so the
interpreter's start and the parsing are its ``BEFORE_RUN`` row. ``StartupTimer.finish`` makes the JSON
record of both (``final_eval.json`` and ``metrics.jsonl`` keep it under ``startup``); ``lines`` prints it as a
table.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bar_policy._phases import MODEL_BUILD, PhaseClock

if TYPE_CHECKING:
    from bar_policy.training.startup.autotune import SeedOutcome

__all__ = ["PHASES", "UNTIL_EPOCH", "UNTIL_EVAL", "ProgramTimes", "StartupTimer", "process_uptime"]

_T_IMPORT = time.monotonic()

BEFORE_RUN = "before run (interpreter, CLI, parsing, env check)"
"""The env check: with ``--env-overrides`` (the reach gpu preset has one) the parser checks them against the
env's config, which imports the env package (jax, MJX); the imports row then holds what is left."""
IMPORTS = "imports (jax, mujoco.mjx, brax or torch)"
DISTRIBUTED = "jax.distributed connect"
ENV_BUILD = "env construction (less the model build)"
RUN_RECORD = "run directory, provenance, logger"
PROGRAMS = "programs (mesh, learner, abstract shapes)"
TRACE = "trace (main thread)"
LOWER = "lower (main thread)"
EXEC_LOAD = "executable cache load (main thread)"
WAIT = "wait for compiles or cache loads, init and reset"
FIRST_EPOCH = "first epoch"
MORE_EPOCHS = "later epochs before the evaluation was compiled"
FIRST_EVAL = "first evaluation (step 0, with its wait)"
OTHER = "other (between the named phases)"
RSL_PROGRAMS = "rsl-rl programs (envs wrapped; resets, steps, quality submitted)"
RSL_IMPORTS = "torch, rsl-rl imports (overlapping the compiles)"
RSL_RESET = "wait for the train reset (compile or cache load) and its run"
RSL_RUNNER = "rsl-rl runner (VecEnv adapters, OnPolicyRunner: actor, critic, storage; a resume's load)"
"""The rsl-rl backend's own rows, in the order they happen: its jax programs are traced, lowered (the
``TRACE`` and ``LOWER`` rows, taken out of ``RSL_PROGRAMS``) and submitted before torch, rsl_rl and
tensordict are imported (``RSL_IMPORTS``), which then runs while XLA compiles on the workers; the training
env's first reset waits for its program (``RSL_RESET``, taken out of ``RSL_RUNNER``: the runner reads the
first observations). Its record holds ``PHASES`` too: ``WAIT`` is its wait for the training step,
``FIRST_EPOCH`` its first iteration, ``MORE_EPOCHS`` the iterations before the evaluation step was
compiled, ``FIRST_EVAL`` its step-0 evaluation."""

PHASES: tuple[str, ...] = (
    BEFORE_RUN,
    IMPORTS,
    DISTRIBUTED,
    MODEL_BUILD,
    ENV_BUILD,
    RUN_RECORD,
    PROGRAMS,
    TRACE,
    LOWER,
    EXEC_LOAD,
    WAIT,
    FIRST_EPOCH,
    MORE_EPOCHS,
    FIRST_EVAL,
    OTHER,
)
"""Every main-thread phase a brax run's record holds (0.0 when it did not happen), in print order."""

UNTIL_EVAL = "first evaluation"
UNTIL_EPOCH = "first epoch"
"""Where a start-up ends (the record's ``until``): the step-0 evaluation (``eval.initial=start``), or the
first epoch when no evaluation runs before training (``end``, ``off``, a resume). ``MORE_EPOCHS`` and
``FIRST_EVAL`` are then 0.0 by construction, and ``lines`` leaves them out."""
_EVAL_ROWS = (MORE_EPOCHS, FIRST_EVAL)

_ORDER: tuple[str, ...] = (
    *PHASES[: PHASES.index(TRACE)],
    RSL_PROGRAMS,
    *PHASES[PHASES.index(TRACE) : PHASES.index(WAIT)],
    RSL_IMPORTS,
    RSL_RESET,
    RSL_RUNNER,
    *PHASES[PHASES.index(WAIT) :],
)
"""Print order of every known row; a backend's rows that are not in it go after them, before ``OTHER``."""


def process_uptime() -> float:
    """Seconds since this process started (Linux ``/proc``; elsewhere since ``breakdown`` was imported)."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        boot_uptime = float(Path("/proc/uptime").read_text().split()[0])
        return max(0.0, boot_uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _T_IMPORT


@dataclass
class ProgramTimes:
    """One compiled program's start-up: seconds per stage, and what the persistent cache did."""

    thread: str = "main"
    """Where it was traced: ``main`` (on the critical path) or ``worker`` (overlapping)."""
    trace_s: float = 0.0
    """Python tracing to a jaxpr (``jit(...).trace``), s."""
    lower_s: float = 0.0
    """Lowering the jaxpr to StableHLO (``Traced.lower``), s."""
    compile_s: float = 0.0
    """``Lowered.compile`` on a worker thread: XLA's compile, or the persistent-cache load on a hit, s."""
    cache_requests: int = 0
    """Compiles that consulted the persistent cache (0: the cache was off)."""
    cache_hits: int = 0
    """Executables loaded from the persistent cache."""
    cache_misses: int = 0
    """Executables compiled and written to the cache."""
    cache_load_s: float = 0.0
    """Seconds spent reading hits from the cache (jax's ``cache_retrieval_time_sec``), s."""
    executable: str = "off"
    """The executable cache (``executable_cache``): ``hit`` (loaded: no trace, lower or compile), ``stored``
    (compiled, then stored), ``not stored: <why>``, ``bad entry replaced, ...`` or ``off``."""
    exec_load_s: float = 0.0
    """Seconds loading the executable on a hit (``deserialize_and_load``), s."""

    @property
    def cache(self) -> str:
        """The persistent cache's outcome: ``hit``, ``miss`` (compiled, stored), ``miss, not stored``.

        Also ``off`` (no lookup) and ``exec cache hit`` (loaded from the executable cache: no lookup).
        """
        if self.executable == "hit":
            return "exec cache hit"
        if self.cache_hits:
            return "hit"
        if self.cache_misses:
            return "miss"
        return "miss, not stored" if self.cache_requests else "off"

    def as_dict(self) -> dict[str, Any]:
        """JSON form (seconds rounded to ms)."""
        return {
            "thread": self.thread,
            "trace_s": round(self.trace_s, 3),
            "lower_s": round(self.lower_s, 3),
            "compile_s": round(self.compile_s, 3),
            "cache": self.cache,
            "cache_load_s": round(self.cache_load_s, 3),
            "executable": self.executable,
            "exec_load_s": round(self.exec_load_s, 3),
        }


@dataclass
class StartupTimer:
    """A run's start-up: exclusive main-thread phases plus per-program times; see the module docstring.

    Args:
        origin: ``time.monotonic()`` that counts as 0 (the process start when the command line passes it).
        origin_name: what ``origin`` is, for the record (``process start`` or ``run() call``).
    """

    origin: float = field(default_factory=time.monotonic)
    origin_name: str = "run() call"
    clock: PhaseClock = field(default_factory=PhaseClock)
    programs: dict[str, ProgramTimes] = field(default_factory=dict)
    report: dict[str, Any] | None = None
    """The record ``finish`` made (None before)."""
    autotune_seed: SeedOutcome | None = None
    """What seeding XLA's autotune cache did (``autotune.seed_autotune_cache``; None: not tried)."""
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def phases(self) -> dict[str, float]:
        """Main-thread phase -> exclusive seconds, as recorded so far."""
        return self.clock.seconds

    def phase(self, name: str) -> AbstractContextManager[None]:
        """Time a block of the main thread as ``name`` (nested phases are taken out of it)."""
        return self.clock.phase(name)

    def add(self, name: str, seconds: float) -> None:
        """Record ``seconds`` measured on the main thread as ``name`` (accumulates)."""
        self.clock.add(name, seconds)

    def active(self) -> AbstractContextManager[PhaseClock]:
        """Let code below training (the env's model build, ``bar_policy._phases.phase``) record here."""
        return self.clock.active()

    def program(self, name: str) -> ProgramTimes:
        """The times of program ``name`` (created on first use; thread-safe)."""
        with self._lock:
            return self.programs.setdefault(name, ProgramTimes())

    def elapsed(self) -> float:
        """Seconds since the origin."""
        return time.monotonic() - self.origin

    def finish(
        self,
        first_epoch_end_s: float,
        stats: dict[str, float] | None = None,
        *,
        total_s: float | None = None,
        until: str = UNTIL_EVAL,
    ) -> dict[str, Any]:
        """The JSON record (also kept as ``report``): origin, totals, every phase, programs, compile counts.

        ``phases`` holds every name of ``PHASES`` (0.0 when it did not happen) and any other phase recorded
        (the rsl-rl backend's rows, printed where they happen: ``RSL_PROGRAMS`` before ``TRACE``, the
        others before ``WAIT``; unknown ones after every known row), ``OTHER`` last: the total less every
        other phase.

        Args:
            first_epoch_end_s: seconds from the origin to the end of the first epoch.
            stats: this run's ``CompileStats`` counts (a difference of two snapshots).
            total_s: seconds from the origin to the end of the start-up (default: now).
            until: what ended the start-up: ``UNTIL_EVAL`` (the step-0 evaluation) or ``UNTIL_EPOCH``.
        """
        total = self.elapsed() if total_s is None else total_s
        named = {k: self.phases.get(k, 0.0) for k in PHASES if k != OTHER}
        named.update({k: v for k, v in self.phases.items() if k not in named})
        rank = {k: i for i, k in enumerate(_ORDER[:-1])}  # known rows in their place, others after (stable)
        named = dict(sorted(named.items(), key=lambda kv: rank.get(kv[0], len(rank))))
        phases = {k: round(v, 3) for k, v in named.items()}
        phases[OTHER] = round(max(0.0, total - sum(named.values())), 3)
        self.report = {
            "origin": self.origin_name,
            "until": until,
            "total_s": round(total, 3),
            "first_epoch_end_s": round(first_epoch_end_s, 3),
            "phases": phases,
            "programs": {k: p.as_dict() for k, p in self.programs.items()},
            "compiles": {k: round(v, 3) for k, v in (stats or {}).items()},
        }
        if self.autotune_seed is not None:
            self.report["autotune_seed"] = self.autotune_seed.as_dict()
        return self.report

    @staticmethod
    def lines(record: dict[str, Any]) -> list[str]:
        """The printed table of a ``record``: phases in order, then programs, then the compile counts."""
        return list(_table(record))


def _table(rec: dict[str, Any]) -> Iterator[str]:
    origin = "process start" if rec["origin"] == "process start" else "run()"
    # Records before "until" existed ended at the first evaluation.
    head = f"start-up: {rec['total_s']:.1f} s from {origin} to"
    if rec.get("until", UNTIL_EVAL) == UNTIL_EVAL:
        rows = rec["phases"]
        yield f"{head} the first evaluation (first epoch done at {rec['first_epoch_end_s']:.1f} s)"
    else:  # no evaluation ran in the start-up: its rows would read 0 s, as if it had been instant
        rows = {k: v for k, v in rec["phases"].items() if k not in _EVAL_ROWS}
        yield (
            f"{head} the end of the first epoch (done at {rec['first_epoch_end_s']:.1f} s; no evaluation "
            "before training)"
        )
    width = max(len(k) for k in rows)
    yield "  main thread, in order (rows add up to the total):"
    for k, v in rows.items():
        yield f"    {k:<{width}}  {v:7.2f} s"
    if rec["programs"]:
        yield "  programs (compiles run on worker threads, overlapping each other and the rows above):"
        w = max(10, *map(len, rec["programs"]))
        head = f"{'program':<{w}} {'traced on':<9} {'trace':>7} {'lower':>7} {'compile':>8}"
        yield f"    {head}  persistent cache; executable cache"
        for name, p in rec["programs"].items():
            load = f" ({p['cache_load_s']:.2f} s load)" if p["cache"] == "hit" else ""
            exe = p.get("executable", "off")
            if exe == "hit":
                load, exe = f" ({p.get('exec_load_s', 0.0):.2f} s load)", "trace, lower, compile skipped"
            yield (
                f"    {name:<{w}} {p['thread']:<9} {p['trace_s']:6.2f}s {p['lower_s']:6.2f}s "
                f"{p['compile_s']:7.2f}s  {p['cache']}{load}; {exe}"
            )
    c = rec["compiles"]
    if c:
        yield (
            f"  XLA compiles: {c['compiles']:.0f} ({c['compile_s']:.1f} s summed over threads); persistent "
            f"cache {c['cache_hits']:.0f} hits ({c['cache_load_s']:.2f} s loading) / "
            f"{c['cache_misses']:.0f} misses"
        )
    if rec.get("autotune_seed"):
        from bar_policy.training.startup.autotune import SeedOutcome

        yield f"  {SeedOutcome(**rec['autotune_seed']).line()}"
