"""Cold start: the persistent compilation cache, concurrent ahead-of-time compiles, a start-up breakdown.

Most of a short run's wall time is XLA compiling the MJX programs (the env step inside the training epoch,
the evaluation, the reset). Five things cut it:

- **Persistent cache** (``configure_compile_cache``): on by default in ``$XDG_CACHE_HOME/bar_policy/jax``
  (``~/.cache/bar_policy/jax``), every program cached whatever its compile time, so a rerun of the same
  command loads executables instead of compiling them.
- **Executable cache** (``bar_policy.training.startup.executable_cache``, handed to ``Compiler``): jax's
  cache is keyed on the lowered program, so a warm run still traces and lowers every program; this one
  stores the serialised executable under a key of everything that determines it (config, package content,
  library versions, devices, argument signature), so a rerun loads it without tracing
  (``docs/training.md``). On by default on GPUs.
- **Autotune seed** (``bar_policy.training.startup.autotune``): XLA's GPU autotuning results shipped for a
  device kind and jaxlib, copied into the cache's per-fusion autotune directory, so a cold compile skips
  timing fusions already timed (about 30 s of an H100's cold start).
- **Concurrent compiles** (``Compiler``): each program is traced in the calling thread (Python, holds the
  GIL) and handed to a thread for XLA's compile (releases the GIL), so the epoch, evaluation and reset
  compile side by side while the next program is traced.
- **A breakdown** (``StartupTimer``, ``bar_policy.training.startup.breakdown``): where the seconds before
  training went (imports, model build, env, each trace, lowering, compile or cache load, first epoch and
  evaluation), printed at the top of a run and kept in its record, so a slow start is visible.
"""

from __future__ import annotations

import contextlib
import os
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bar_policy.training.startup.breakdown import ProgramTimes, StartupTimer
from bar_policy.training.startup.heartbeat import Heartbeat

if TYPE_CHECKING:
    from bar_policy.training.startup.executable_cache import ExecutableCache

__all__ = [
    "QUICK_COMPILE",
    "QUICK_COMPILE_NOTE",
    "CompileStats",
    "Compiler",
    "configure_compile_cache",
    "default_cache_dir",
    "process_uptime",
    "quiet_xla_alarms",
]

_T_IMPORT = time.monotonic()

QUICK_COMPILE: dict[str, Any] = {"xla_backend_optimization_level": 1}
"""XLA options of ``TrainConfig.quick_compile`` (the tiny preset's): LLVM's code generation at -O1 instead
of the default -O2/-O3 pipeline; XLA's HLO passes (fusion, layout) still run. The tiny preset's evaluation
on the 2-core CPU (process CPU seconds, jaxlib 0.10.2, 2026-12-02): compile 39.2 s at -O1, 48.8 s with only
``xla_llvm_disable_expensive_passes``, one run 2.07 and 2.01 s; at -O0 it compiled faster still but ran
several times slower, which three evaluations per run paid back (docs/training.md, "Smoke run")."""
QUICK_COMPILE_NOTE = (
    "quick compile: XLA's LLVM at -O1 (smoke-run programs: compile sooner, run about as fast; "
    "--no-quick-compile turns it off)"
)


def quiet_xla_alarms() -> str:
    """Keep XLA's C++ log to fatal messages; returns the note that says so.

    XLA logs ``slow_operation_alarm`` errors ("Very slow compile?", "Constant folding an instruction is
    taking > 1s") while a CPU compile runs long: a newcomer's smoke run showed nothing else for minutes
    and read them as a fault. The start-up's own lines (``startup.heartbeat``) say what compiles instead.
    jax's ``jax_logging_level`` sets the same absl level but also re-levels jax's Python loggers; this
    sets the C++ one only (process-wide, from now on). Failures still raise in Python.
    """
    from jax._src.lib import utils

    utils.absl_set_min_log_level(3)  # absl: 0 info, 1 warning, 2 error, 3 fatal
    return "XLA's C++ log: fatal only (its slow-compile alarms; the start-up lines say what compiles)"


def process_uptime() -> float:
    """Seconds since this process started (Linux ``/proc``; elsewhere since this module was imported)."""
    try:
        start_ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])
        boot_uptime = float(Path("/proc/uptime").read_text().split()[0])
        return max(0.0, boot_uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return time.monotonic() - _T_IMPORT


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/bar_policy/jax``, or ``~/.cache/bar_policy/jax`` without XDG_CACHE_HOME."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "bar_policy" / "jax"


def configure_compile_cache(enabled: bool = True, directory: str = "") -> Path | None:
    """Switch jax's persistent compilation cache on (every program) or off; returns the directory used.

    Precedence of the directory: ``directory`` (``--compile-cache-dir``), then ``JAX_COMPILATION_CACHE_DIR``,
    then ``default_cache_dir()``. Call before the first compile: jax opens the cache once per process.

    Args:
        enabled: False turns the cache off (``jax_enable_compilation_cache``).
        directory: explicit cache directory ('' = the precedence above).

    Returns:
        The cache directory, or None when the cache is off.
    """
    import jax

    if not enabled:
        jax.config.update("jax_enable_compilation_cache", False)
        return None
    path = Path(directory or os.environ.get("JAX_COMPILATION_CACHE_DIR") or default_cache_dir()).expanduser()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    # Every program, however quick to compile: a warm start then compiles nothing at all.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


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

    With ``say`` (prints a line) its heartbeat (``startup.heartbeat``) is told each program's stage and says
    what the start-up is doing; ``compiler_options`` go to every ``Lowered.compile`` (XLA debug options, e.g.
    ``QUICK_COMPILE``).
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
