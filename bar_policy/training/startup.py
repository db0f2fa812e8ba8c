"""Cold start: the persistent compilation cache, concurrent ahead-of-time compiles, a start-up breakdown.

Most of a short run's wall time is XLA compiling the MJX programs (the env step inside the training epoch,
the evaluation, the reset). Three things cut it:

- **Persistent cache** (``configure_compile_cache``): on by default in ``$XDG_CACHE_HOME/bar_policy/jax``
  (``~/.cache/bar_policy/jax``), every program cached whatever its compile time, so a rerun of the same
  command loads executables instead of compiling them.
- **Concurrent compiles** (``Compiler``): each program is traced in the calling thread (Python, holds the
  GIL) and handed to a thread for XLA's compile (releases the GIL), so the epoch, evaluation and reset
  compile side by side while the next program is traced.
- **A breakdown** (``StartupTimer``): where the seconds before the first progress line went (interpreter
  and imports, env build, each trace and compile, first epoch), printed at the top of a run so a slow start
  is visible.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "CompileStats",
    "Compiler",
    "StartupTimer",
    "configure_compile_cache",
    "default_cache_dir",
    "process_uptime",
]

_T_IMPORT = time.monotonic()


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
    """Counts XLA compiles and persistent-cache hits in this process (``jax.monitoring`` listeners)."""

    _instance: CompileStats | None = None
    _lock = threading.Lock()

    def __init__(self) -> None:
        self.compiles = 0
        """Backend compiles requested (cache hits included)."""
        self.compile_s = 0.0
        """Seconds spent in them (summed over threads)."""
        self.cache_hits = 0
        self.cache_misses = 0

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

    def _on_event(self, event: str, **_: Any) -> None:
        if event == "/jax/compilation_cache/cache_hits":
            self.cache_hits += 1
        elif event == "/jax/compilation_cache/cache_misses":
            self.cache_misses += 1

    def _on_duration(self, event: str, duration: float, **_: Any) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            self.compiles += 1
            self.compile_s += duration

    def snapshot(self) -> dict[str, float]:
        """Current counts."""
        return {
            "compiles": self.compiles,
            "compile_s": self.compile_s,
            "cache_hits": self.cache_hits,
            "cache_misses": self.cache_misses,
        }


@dataclass
class StartupTimer:
    """Named phases of a run's start, in seconds, printed as one block."""

    phases: dict[str, float] = field(default_factory=dict)
    """Phase -> seconds (insertion order is print order)."""
    t_start: float = field(default_factory=time.monotonic)

    def add(self, name: str, seconds: float) -> None:
        """Record (or accumulate into) a phase."""
        self.phases[name] = self.phases.get(name, 0.0) + seconds

    def lines(self, total_s: float, stats: dict[str, float] | None = None) -> list[str]:
        """The printed block: one line per phase, then the compile counts."""
        width = max((len(k) for k in self.phases), default=10)
        out = [f"start-up: {total_s:.1f} s to the end of the first epoch (compiles overlap: see 'wait')"]
        out += [f"  {k:<{width}}  {v:7.1f} s" for k, v in self.phases.items()]
        if stats:
            out.append(
                f"  XLA compiles: {stats['compiles']:.0f} ({stats['compile_s']:.1f} s summed over threads), "
                f"persistent cache {stats['cache_hits']:.0f} hits / {stats['cache_misses']:.0f} misses"
            )
        return out


class Compiler:
    """Ahead-of-time compiles on worker threads: trace here, compile there, collect when needed.

    ``submit(name, jitted, *args)`` lowers ``jitted`` for ``args`` (arrays or ``ShapeDtypeStruct``s) in the
    calling thread (or, with ``background=True``, on the worker) and compiles it on a worker; ``get(name)``
    waits for the compiled executable. The trace and compile seconds of each program go into the
    ``StartupTimer``.
    """

    def __init__(self, timer: StartupTimer, max_workers: int = 4) -> None:
        self.timer = timer
        self._pool = ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="xla-compile")
        self._futures: dict[str, Future] = {}

    def submit(self, name: str, jitted: Callable[..., Any], *args: Any, background: bool = False) -> Any:
        """Trace/lower now, compile in the background; returns the ``Lowered`` (its ``out_info``).

        With ``background=True`` the trace runs on the worker too and None is returned: for a program
        nothing waits on soon (the evaluation), whose trace then overlaps the first epochs instead of
        delaying them. Tracing holds the GIL, so submit it after the programs this thread traces next.
        """

        def trace() -> Any:
            t0 = time.monotonic()
            lowered = jitted.lower(*args)  # type: ignore[attr-defined]
            self.timer.add(f"trace {name}" + (" (worker)" if background else ""), time.monotonic() - t0)
            return lowered

        def compile_it(lowered: Any) -> tuple[Any, float]:
            t = time.monotonic()
            return lowered.compile(), time.monotonic() - t

        if background:
            self._futures[name] = self._pool.submit(lambda: compile_it(trace()))
            return None
        lowered = trace()
        self._futures[name] = self._pool.submit(compile_it, lowered)
        return lowered

    def done(self, name: str) -> bool:
        """Whether ``name`` finished compiling."""
        return self._futures[name].done()

    def get(self, name: str) -> Any:
        """The compiled executable of ``name`` (waits for it; re-raises its compile error)."""
        fut = self._futures[name]
        compiled, seconds = fut.result()
        key = f"compile {name}"
        if key not in self.timer.phases:
            self.timer.add(key, seconds)
        return compiled

    def close(self) -> None:
        """Release the worker threads."""
        self._pool.shutdown(wait=False)
