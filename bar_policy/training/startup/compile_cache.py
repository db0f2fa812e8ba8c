"""jax's compile settings a run starts with: the persistent compilation cache and the quick-compile options.

``StartUp.begin`` (``startup.session``) calls ``configure_compile_cache`` before the first compile (jax
opens the cache once per process): on by default in ``$XDG_CACHE_HOME/bar_policy/jax``
(``~/.cache/bar_policy/jax``), every program cached whatever its compile time, so a rerun of the same
command loads executables instead of compiling them. ``QUICK_COMPILE`` are the XLA options every program of
a ``quick_compile`` run compiles with (``compiler.Compiler``), and ``quiet_xla_alarms`` keeps XLA's C++ log
quiet while such a run compiles long.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = [
    "QUICK_COMPILE",
    "QUICK_COMPILE_NOTE",
    "configure_compile_cache",
    "default_cache_dir",
    "quiet_xla_alarms",
]

QUICK_COMPILE: dict[str, Any] = {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False}
"""XLA options of ``TrainConfig.quick_compile`` (the tiny preset's): LLVM's code generation at -O1 instead
of the default -O2/-O3 pipeline; XLA's HLO passes (fusion, layout) still run. The tiny preset's evaluation
on the 2-core CPU (process CPU seconds, jaxlib 0.10.2, 2026-12-02): compile 39.2 s at -O1, 48.8 s with only
``xla_llvm_disable_expensive_passes``, one run 2.07 and 2.01 s; at -O0 it compiled faster still but ran
several times slower, which three evaluations per run paid back (docs/training.md, "Smoke run").
``xla_cpu_use_fusion_emitters`` off: XLA's CPU backend writes each fusion's loop with its older emitters, and
the whole cold smoke run took 147.6 CPU s and 1.18 GB against 219.6 s and 2.96 GB (the env step ran as fast;
float32 results differ in rounding only; 2-core CPU, 2026-12-03). A GPU compile ignores it."""
QUICK_COMPILE_NOTE = (
    "quick compile: XLA's LLVM at -O1, its older CPU fusion emitters (smoke-run programs: compile sooner, "
    "run about as fast; --no-quick-compile turns it off)"
)


def quiet_xla_alarms() -> str:
    """Keep XLA's C++ log to fatal messages; returns the note that says so.

    XLA logs ``slow_operation_alarm`` errors ("Very slow compile?", "Constant folding an instruction is
    taking > 1s") while a CPU compile runs long: a newcomer's smoke run showed nothing else for minutes
    and read them as a fault. The start-up's own lines (``compiler.Heartbeat``) say what compiles instead.
    jax's ``jax_logging_level`` sets the same absl level but also re-levels jax's Python loggers; this
    sets the C++ one only (process-wide, from now on). Failures still raise in Python.
    """
    from jax._src.lib import utils

    utils.absl_set_min_log_level(3)  # absl: 0 info, 1 warning, 2 error, 3 fatal
    return "XLA's C++ log: fatal only (its slow-compile alarms; the start-up lines say what compiles)"


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
