"""Ahead-of-time compiles on worker threads, what jax compiled meanwhile, and the lines saying what compiles.

Most of a short run's wall time is XLA compiling the MJX programs (the env step inside the training epoch,
the evaluation, the reset). Besides jax's persistent cache (``startup.compile_cache``) and XLA's autotune
seed (``startup.autotune``), three things here cut it or make it visible:

- **Concurrent compiles** (``Compiler``): each program is traced in the calling thread (Python, holds the
  GIL) and handed to a thread for XLA's compile (releases the GIL), so the epoch, evaluation and reset
  compile side by side while the next program is traced.
- **Executable cache** (``bar_policy.training.startup.executable_cache``, handed to ``Compiler``): jax's
  cache is keyed on the lowered program, so a warm run still traces and lowers every program; this one
  stores the serialised executable under a key of everything that determines it (config, package content,
  library versions, devices, argument signature), so a rerun loads it without tracing
  (``docs/training.md``). On by default on GPUs.
- **What it is doing** (``Heartbeat``, driven by ``Compiler``): a cold start on a CPU spends minutes in XLA,
  and without these lines the terminal showed nothing but the run header (and, past two minutes of one
  compile, XLA's own ``slow_operation_alarm`` "Very slow compile?", which reads like a fault). The
  heartbeat keeps each program's stage (``STAGES``) and

  - prints one line when a program is done (``rollout: compiled in 35.1 s``, ``... loaded from the
    compile cache in 0.4 s``, ``... loaded from the executable cache in 0.2 s``);
  - every ``interval_s`` while any program is unfinished, one line of what each unfinished program is
    doing and for how long: ``start-up 23 s: rollout compiling (XLA, 12 s), evaluate tracing (3 s); done:
    reset``.

  Its lines start with ``start-up`` or ``  program`` so a reader (and tests/training/test_smoke_run.py) can
  tell them from the progress lines. The printing thread stops once every program is done (``close``).

Every stage's seconds go into the start-up breakdown (``StartupTimer``, ``startup.breakdown``): where the
seconds before training went (imports, model build, env, each trace, lowering, compile or cache load, first
epoch and evaluation), printed at the top of a run and kept in its record, so a slow start is visible;
``CompileStats`` counts the compiles and persistent-cache outcomes jax reports.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bar_policy.training.startup.breakdown import ProgramTimes, StartupTimer

if TYPE_CHECKING:
    from bar_policy.training.startup.executable_cache import ExecutableCache

__all__ = ["STAGES", "CompileStats", "Compiler", "Heartbeat"]


STAGES = ("queued", "tracing", "lowering", "compiling", "loading", "done", "failed")
"""A program's stages in order: ``compiling`` is XLA's compile (or jax's persistent-cache lookup and load:
which of the two is known only once it ends), ``loading`` an executable-cache load."""

_SAY_STAGE = {
    "queued": "queued",
    "tracing": "tracing",
    "lowering": "lowering",
    "compiling": "compiling (XLA)",
    "loading": "loading from the executable cache",
}


@dataclass
class _Stage:
    stage: str = "queued"
    since: float = 0.0


class Heartbeat:
    """Stages of a run's programs and the lines about them (module docstring).

    Args:
        say: prints one line (the run logger's ``print``).
        clock_origin: ``time.monotonic()`` the ``start-up N s`` figure counts from (the timer's origin).
        interval_s: seconds between two status lines while a program is unfinished.
    """

    def __init__(self, say: Callable[[str], None], clock_origin: float, interval_s: float = 5.0) -> None:
        self.say = say
        self.origin = clock_origin
        self.interval_s = interval_s
        self._stages: dict[str, _Stage] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._thread: threading.Thread | None = None

    def set(self, name: str, stage: str) -> None:
        """Program ``name`` entered ``stage`` (one of ``STAGES``); starts the printing thread at first use."""
        if stage not in STAGES:
            raise ValueError(f"unknown stage {stage!r}; valid: {list(STAGES)}")
        with self._lock:
            self._stages[name] = _Stage(stage, time.monotonic())
            if self._thread is None and not self._stop:
                self._thread = threading.Thread(target=self._loop, name="startup-heartbeat", daemon=True)
                self._thread.start()

    def finished(self, name: str, how: str) -> None:
        """Program ``name`` is ready: ``how`` it got so (``compiled in 35.1 s``); prints that line."""
        self.set(name, "done")
        self.say(f"  program {name}: {how}")
        if self.all_done():
            self._wake.set()

    def failed(self, name: str, error: BaseException) -> None:
        """Program ``name`` failed (its error is raised where the program is read)."""
        self.set(name, "failed")
        self.say(f"  program {name}: failed ({type(error).__name__})")

    def all_done(self) -> bool:
        """Whether every program known so far is done or failed."""
        with self._lock:
            return all(s.stage in ("done", "failed") for s in self._stages.values())

    def status_line(self, now: float | None = None) -> str | None:
        """The line about the unfinished programs (None when every one is done)."""
        now = time.monotonic() if now is None else now
        with self._lock:
            items = list(self._stages.items())
        busy = [
            f"{n} {_SAY_STAGE[s.stage]} ({now - s.since:.0f} s)"
            for n, s in items
            if s.stage not in ("done", "failed")
        ]
        if not busy:
            return None
        done = [n for n, s in items if s.stage == "done"]
        tail = f"; done: {', '.join(done)}" if done else ""
        return f"start-up {now - self.origin:.0f} s: {', '.join(busy)}{tail}"

    def close(self) -> None:
        """Stop the printing thread (its last line is not printed)."""
        self._stop = True
        self._wake.set()

    def _loop(self) -> None:
        while not self._stop:
            self._wake.wait(self.interval_s)
            self._wake.clear()
            if self._stop or self.all_done():
                return
            line = self.status_line()
            if line is not None:
                self.say(line)


class CompileStats:
    """Counts XLA compiles and persistent-cache outcomes in this process (``jax.monitoring`` listeners).

    The event names are jax's (0.10: ``jax/_src/compiler.py``, ``compilation_cache.py``, ``dispatch.py``).
    A compile that runs inside ``attribute(times)`` (on any thread) also counts into that program's
    ``ProgramTimes``: jax records the events on the thread that compiles.
    """

    _instance: CompileStats | None = None
    _lock = threading.Lock()

    def __init__(self) -> None:
        self.compiles = 0
        """Backend compiles requested (cache hits included)."""
        self.compile_s = 0.0
        """Seconds spent in them (summed over threads)."""
        self.cache_hits = 0
        self.cache_misses = 0
        """Executables compiled and written to the persistent cache."""
        self.cache_load_s = 0.0
        """Seconds spent loading cache hits."""
        self.trace_s = 0.0
        """jax's own jaxpr-trace seconds, every function (eager ones too), summed over threads."""
        self.lower_s = 0.0
        """jax's own jaxpr-to-MLIR seconds, summed over threads."""
        self._local = threading.local()

    @classmethod
    def get(cls) -> CompileStats:
        """The process-wide instance (listeners registered on first use)."""
        with cls._lock:
            if cls._instance is None:
                import jax

                inst = cls()
                jax.monitoring.register_event_listener(inst._on_event)
                jax.monitoring.register_event_duration_secs_listener(inst._on_duration)
                cls._instance = inst
            return cls._instance

    @contextlib.contextmanager
    def attribute(self, times: ProgramTimes) -> Iterator[None]:
        """Count the cache events of compiles run by this thread in the block into ``times`` too."""
        previous = getattr(self._local, "target", None)
        self._local.target = times
        try:
            yield
        finally:
            self._local.target = previous

    def _on_event(self, event: str, **_: Any) -> None:
        target: ProgramTimes | None = getattr(self._local, "target", None)
        if event == "/jax/compilation_cache/cache_hits":
            self.cache_hits += 1
            if target is not None:
                target.cache_hits += 1
        elif event == "/jax/compilation_cache/cache_misses":
            self.cache_misses += 1
            if target is not None:
                target.cache_misses += 1
        elif event == "/jax/compilation_cache/compile_requests_use_cache" and target is not None:
            target.cache_requests += 1

    def _on_duration(self, event: str, duration: float, **_: Any) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            self.compiles += 1
            self.compile_s += duration
        elif event == "/jax/compilation_cache/cache_retrieval_time_sec":
            self.cache_load_s += duration
            target: ProgramTimes | None = getattr(self._local, "target", None)
            if target is not None:
                target.cache_load_s += duration
        elif event == "/jax/core/compile/jaxpr_trace_duration":
            self.trace_s += duration
        elif event == "/jax/core/compile/jaxpr_to_mlir_module_duration":
            self.lower_s += duration

    def snapshot(self) -> dict[str, float]:
        """Current counts and seconds (subtract two snapshots for what happened in between)."""
        return {
            "compiles": self.compiles,
            "compile_s": self.compile_s,
            "cache_hits": self.cache_hits,
            "cache_misses": self.cache_misses,
            "cache_load_s": self.cache_load_s,
            "jax_trace_s": self.trace_s,
            "jax_lower_s": self.lower_s,
        }


class Compiler:
    """Ahead-of-time compiles on worker threads: trace and lower here, compile there, collect when needed.

    ``submit(name, jitted, *args)`` traces (``jitted.trace``) and lowers (``Traced.lower``) ``jitted`` for
    ``args`` (arrays or ``ShapeDtypeStruct``s) in the calling thread (or, with ``background=True``, on the
    worker) and compiles it on a worker; ``get(name)`` waits for the compiled executable. Each stage's
    seconds and the program's persistent-cache outcome go into ``timer.programs[name]``; the calling
    thread's trace and lower seconds also into the timer's ``TRACE`` and ``LOWER`` phases.

    With an ``executable_cache`` (``bar_policy.training.startup.executable_cache``) a program whose key is
    stored is loaded instead (in the calling thread, or on the worker with ``background=True``): no trace, no
    lowering, no compile; a miss is compiled as above and its executable stored.

    With ``say`` (prints a line) its heartbeat (``Heartbeat``) is told each program's stage and says
    what the start-up is doing; ``compiler_options`` go to every ``Lowered.compile`` (XLA debug options, e.g.
    ``compile_cache.QUICK_COMPILE``).
    """

    def __init__(
        self,
        timer: StartupTimer,
        max_workers: int = 4,
        executable_cache: ExecutableCache | None = None,
        *,
        say: Callable[[str], None] | None = None,
        compiler_options: dict[str, Any] | None = None,
    ) -> None:
        self.timer = timer
        self.executable_cache = executable_cache
        self.heartbeat = Heartbeat(say, timer.origin) if say is not None else None
        self.compiler_options = dict(compiler_options or {})
        self._pool = ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="xla-compile")
        self._futures: dict[str, Future] = {}
        self._stats = CompileStats.get()

    def submit(
        self,
        name: str,
        jitted: Callable[..., Any],
        *args: Any,
        background: bool = False,
        load_in_background: bool = False,
    ) -> Any:
        """Trace and lower now, compile in the background; returns the ``Lowered`` (its ``out_info``).

        With ``background=True`` the trace runs on the worker too and None is returned: for a program
        nothing waits on soon (the evaluation), whose trace then overlaps the first epochs instead of
        delaying them. Tracing holds the GIL, so submit it after the programs this thread traces next.
        On an executable-cache hit the loaded ``Compiled`` is returned instead (it has ``out_info`` too).
        With ``load_in_background=True`` a stored program is loaded on a worker (None is returned, as with
        ``background``; an unusable entry is then traced and compiled there) while a program to compile is
        still traced here: for a program whose result the caller does not read (a warm start's brax update or
        rsl-rl step, whose seconds of loading then overlap what this thread does next).
        """
        from bar_policy.training.parallel import all_agree
        from bar_policy.training.startup.breakdown import EXEC_LOAD, LOWER, TRACE

        cache = self.executable_cache
        key, inputs = cache.key(name, jitted, args) if cache is not None else ("", {})
        # Under several processes all load the program or none does (each compiles it, as a cold run).
        stored = all_agree(f"executable {name}", cache is not None and cache.has(key))
        if load_in_background and stored:
            background = True
        times = self.timer.program(name)
        times.thread = "worker" if background else "main"
        beat = self.heartbeat
        stage = (lambda s: beat.set(name, s)) if beat is not None else (lambda s: None)
        stage("queued")

        def load() -> Any:
            t = time.monotonic()
            if cache is not None and stored:
                stage("loading")
            compiled = cache.load(key, name) if cache is not None and stored else None
            if compiled is not None:
                times.executable, times.exec_load_s = "hit", time.monotonic() - t
                if not background:
                    self.timer.add(EXEC_LOAD, times.exec_load_s)
                if beat is not None:
                    beat.finished(name, f"loaded from the executable cache in {times.exec_load_s:.1f} s")
            return compiled

        def trace_and_lower() -> Any:
            t0 = time.monotonic()
            try:
                stage("tracing")
                traced = jitted.trace(*args)  # type: ignore[attr-defined]
                t1 = time.monotonic()
                stage("lowering")
                lowered = traced.lower()
            except BaseException as e:
                if beat is not None:
                    beat.failed(name, e)
                raise
            t2 = time.monotonic()
            times.trace_s, times.lower_s = t1 - t0, t2 - t1
            if not background:
                self.timer.add(TRACE, t1 - t0)
                self.timer.add(LOWER, t2 - t1)
            return lowered

        def compile_it(lowered: Any) -> Any:
            t = time.monotonic()
            stage("compiling")
            try:
                with self._stats.attribute(times):
                    compiled = lowered.compile(self.compiler_options or None)
            except BaseException as e:
                if beat is not None:
                    beat.failed(name, e)
                raise
            times.compile_s = time.monotonic() - t
            if beat is not None:
                how = "loaded from the compile cache" if times.cache_hits else "compiled"
                beat.finished(name, f"{how} in {times.compile_s:.1f} s")
            if cache is not None and times.cache_hits:
                # An executable jax's persistent cache served does not re-serialise whole on a CPU (jaxlib
                # 0.10.2: its reload misses the fused functions, "Function ... not found"): not stored.
                times.executable = "not stored: served by jax's persistent cache"
            elif cache is not None:
                stored = cache.store(key, inputs, compiled)
                times.executable = f"bad entry replaced, {stored}" if key in cache.rejected else stored
            return compiled

        if background:

            def everything() -> Any:
                compiled = load()
                return compiled if compiled is not None else compile_it(trace_and_lower())

            self._futures[name] = self._pool.submit(everything)
            return None
        compiled = load()
        if compiled is not None:
            done: Future = Future()
            done.set_result(compiled)
            self._futures[name] = done
            return compiled
        lowered = trace_and_lower()
        self._futures[name] = self._pool.submit(compile_it, lowered)
        return lowered

    def done(self, name: str) -> bool:
        """Whether ``name`` finished compiling."""
        return self._futures[name].done()

    def get(self, name: str) -> Any:
        """The compiled executable of ``name`` (waits for it; re-raises its trace or compile error)."""
        return self._futures[name].result()

    def confirm(self) -> None:
        """The programs loaded from the executable cache ran: they are no longer suspects of a crash."""
        if self.executable_cache is not None:
            self.executable_cache.confirm()

    def close(self) -> None:
        """Release the worker threads (and stop the heartbeat's)."""
        self._pool.shutdown(wait=False)
        if self.heartbeat is not None:
            self.heartbeat.close()
