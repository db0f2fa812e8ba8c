"""Environment a run sets before jax starts its backend: torch's GPU memory, XLA's scheduling, CPU threads.

``set_backend_env(cfg)`` runs first in ``run`` (before anything touches a device) and returns the notes the
run prints under its header:

- **GPU memory on demand.** ``XLA_PYTHON_CLIENT_PREALLOCATE=false``: jax grows its pool as programs need it
  instead of reserving 75 % of the GPU at its first transfer, unless the user set it or
  ``XLA_PYTHON_CLIENT_MEM_FRACTION``. That reservation was the model build's time on a GPU (the env's first
  ``device_put``): 2.37 s cold and 1.44 s warm on an H200, against 0.12 and 0.05 s without it, at the same
  steady rate (324 k against 321 k env steps/s; docs/performance.md, 2026-12-01). rsl-rl runs need it for
  torch's share of the memory, on any platform; a CPU-only brax run has no pool, so nothing is set there.
- **Command buffers that run independent kernels at once.** XLA records runs of a GPU program's kernels into
  command buffers (CUDA graphs). By default (``LHS``) each buffer runs its kernels one after another;
  ``--xla_gpu_command_buffer_scheduling_mode=CONCURRENT`` gives the graph the program's own buffer
  dependencies instead, so kernels that do not depend on each other run side by side. The MJX step and the
  update are bound by the number of their small kernels, not by the device's arithmetic (docs/performance.md
  2026-11-27), so on one H100 at the gpu preset's batch the rollout took 114 instead of 129 ms and the
  update (128 Adam steps) 32 instead of 51 ms (2026-11-27). A run whose jax has a GPU appends the flag to
  ``XLA_FLAGS`` unless ``XLA_FLAGS`` already names it (the user's choice stays). The executable cache keys
  on ``XLA_FLAGS``, so programs compiled under either mode are never served to the other.
- **Newton loops recorded whole for a written-out Cholesky.** An env built with ``cholesky=columns`` or
  ``scalar`` (``--env-overrides``; docs/physics.md section 5) has no library call left in its physics step,
  so XLA can record MJX's Newton ``while`` loop as one graph node, but only when ``WHILE`` is among the
  command-buffer types, which by default it is not. Without it that form is no faster than ``library`` and
  compiles longer; with it reach trained at 1.17x (docs/performance.md, 2026-11-28) and its iteration took
  84.8 against 96.9 ms (2026-11-29). Such a run appends ``GRAPHED_LOOPS`` unless ``XLA_FLAGS`` already
  names ``--xla_gpu_enable_command_buffer`` (the user's set stays).
- **A deadlock of jaxlib 0.10's CPU LAPACK kernels.** jaxlib < 0.11 splits a batched LAPACK call (Cholesky,
  triangular solve) over XLA's CPU thread pool once ``batch x cost per matrix >= 200,000`` and the pool has
  more than one thread, and the calling thread waits for the pieces. The MJX step has two independent
  batched Choleskys per physics substep (the mass matrix and the constraint solver's Hessian, nv = 14:
  914 per matrix), so from 219 envs per device XLA may run both at once, one on each thread of a 2-thread
  pool, each waiting for pieces no free thread will run: the process stops for good (on this project's
  2-core CPU, ``--ppo.num-envs 256`` and 512 hung in their first epoch; gdb: both ``tf_XLAEigen`` threads in
  ``lapack_spotrf_ffi -> ParallelBatchMap -> BlockingCounter::Wait``). jax fixed it upstream after 0.11.0
  (the kernels no longer split in open-source builds). A 1-thread pool never splits, so on a CPU-only run
  with such a jaxlib and at most ``SMALL_CPU`` cores this sets ``PJRT_NPROC=1`` (the size of XLA's CPU pool),
  unless the user set it. On the 2-core CPU that also trained faster: 876 against 766 env steps/s at 128
  envs. A larger pool avoids the deadlock while fewer LAPACK calls run at once than it has threads (3 and 4
  threads ran at 256 envs), so more cores are left alone; ``PJRT_NPROC=1`` in the environment is the
  remedy there if a run stops. If jax's backend is already running (a library caller used jax first), the
  variable would do nothing: a note says so instead.
"""

from __future__ import annotations

import importlib.metadata
import os
from typing import Any

from bar_policy.overrides import split_override

__all__ = [
    "GRAPHED_LOOPS",
    "MEMORY_VARS",
    "PREALLOCATE",
    "SCHEDULING",
    "SMALL_CPU",
    "WRITTEN_OUT",
    "cpu_threads_decision",
    "loops_decision",
    "memory_decision",
    "scheduling_decision",
    "set_backend_env",
]

SMALL_CPU = 2
"""Cores (this process's CPU affinity) up to which a CPU-only run on an affected jaxlib gets one XLA
thread."""

NPROC = "PJRT_NPROC"
"""The environment variable XLA reads for its CPU thread pool's size."""

SCHEDULING = "--xla_gpu_command_buffer_scheduling_mode=CONCURRENT"
"""The XLA flag a GPU run adds (module docstring): command buffers ordered by their buffer dependencies."""

GRAPHED_LOOPS = "--xla_gpu_enable_command_buffer=+WHILE"
"""The XLA flag a GPU run on a written-out Cholesky adds: while loops join the command-buffer types."""

PREALLOCATE = "XLA_PYTHON_CLIENT_PREALLOCATE"
"""The variable that makes jax's GPU client reserve its pool at start (``false``: grow on demand)."""

MEMORY_VARS = (PREALLOCATE, "XLA_PYTHON_CLIENT_MEM_FRACTION")
"""The user's choices of jax's GPU memory: either one set leaves the memory part alone."""

WRITTEN_OUT = ("columns", "scalar")
"""The env's ``cholesky`` forms with no library call in the step (``envs.physics_step.CHOLESKY``)."""


def _names(xla_flags: str, flag: str) -> bool:
    """Whether ``xla_flags`` sets ``flag`` (the name before ``=``; a longer name is another flag)."""
    name = flag.split("=")[0]
    return any(f.split("=")[0] == name for f in xla_flags.split())


def scheduling_decision(*, cpu_only: bool, xla_flags: str, backend_started: bool) -> str:
    """Whether to add ``SCHEDULING`` to ``XLA_FLAGS`` (``xla_flags``): ``set``, ``note`` or ``none``.

    ``set``: append it; ``note``: a GPU run whose backend already runs (the flag would do nothing: a note
    says so); ``none``: a CPU-only run (XLA's CPU programs have no command buffers) or ``xla_flags``
    already sets the scheduling mode.
    """
    if cpu_only or _names(xla_flags, SCHEDULING):
        return "none"
    return "note" if backend_started else "set"


def loops_decision(
    *, cpu_only: bool, xla_flags: str, env_overrides: tuple[str, ...], backend_started: bool
) -> str:
    """Whether to add ``GRAPHED_LOOPS`` to ``xla_flags``: ``set``, ``note`` or ``none`` (as above).

    ``env_overrides``: the run's ``key=value`` env items; only a ``cholesky`` among ``WRITTEN_OUT`` asks for
    it (the env's own default is ``library``). ``none`` too when ``xla_flags`` already sets the
    command-buffer types.
    """
    forms = [value for path, value in map(split_override, env_overrides) if path == "cholesky"]
    if cpu_only or not forms or forms[-1] not in WRITTEN_OUT or _names(xla_flags, GRAPHED_LOOPS):
        return "none"
    return "note" if backend_started else "set"


def memory_decision(*, cpu_only: bool, backend: str, user_set: bool, backend_started: bool) -> str:
    """Whether to set ``PREALLOCATE`` to ``false`` (module docstring): ``set``, ``note`` or ``none``.

    ``set`` for a GPU run and for every rsl-rl run (torch's memory; where jax has no GPU the variable is
    harmless); ``note``: a GPU run whose backend already runs (the variable would do nothing); ``none``: a
    CPU-only brax run (no pool to reserve), or the user chose (``user_set``: one of ``MEMORY_VARS`` is in the
    environment).
    """
    if user_set or (cpu_only and backend != "rsl-rl"):
        return "none"
    return "note" if backend_started and not cpu_only else "set"


def cpu_threads_decision(
    *, cpu_only: bool, jaxlib_version: str, cores: int, user_set: bool, backend_started: bool
) -> str:
    """What to do about the LAPACK deadlock (module docstring): ``set``, ``note`` or ``none``.

    ``set``: set ``PJRT_NPROC=1``; ``note``: the conditions hold but the backend already runs (only a note
    can help); ``none``: not affected (a GPU run, jaxlib >= 0.11, more than ``SMALL_CPU`` cores) or the user
    chose the pool size.
    """
    major_minor = tuple(int(p) for p in jaxlib_version.split(".")[:2])
    if not cpu_only or major_minor >= (0, 11) or cores > SMALL_CPU or user_set:
        return "none"
    return "note" if backend_started else "set"


def _cpu_only() -> bool:
    """Whether jax will run on the CPU alone.

    ``JAX_PLATFORMS`` (or jax's config) names only ``cpu``, or no accelerator plugin is installed (the
    ``jax_plugins`` entry points: jax-cuda12/13, ROCm, TPU).
    """
    import jax

    platforms = (jax.config.jax_platforms or os.environ.get("JAX_PLATFORMS") or "").strip()
    if platforms:
        return all(p.strip() == "cpu" for p in platforms.split(","))
    return not list(importlib.metadata.entry_points(group="jax_plugins"))


def set_backend_env(cfg: Any) -> list[str]:
    """Set the variables above for ``cfg`` (a ``TrainConfig``) where they apply; returns the run's notes."""
    import jaxlib
    from jax._src import xla_bridge

    notes = []
    cpu_only, started = _cpu_only(), xla_bridge.backends_are_initialized()
    flags = os.environ.get("XLA_FLAGS", "")
    scheduling = scheduling_decision(cpu_only=cpu_only, xla_flags=flags, backend_started=started)
    if scheduling == "set":
        os.environ["XLA_FLAGS"] = f"{flags} {SCHEDULING}".strip()
        notes.append(f"XLA: {SCHEDULING} (independent kernels run at once; training.startup.backend_env)")
    elif scheduling == "note":
        notes.append(f"note: jax's GPU backend already runs, so XLA_FLAGS lacks {SCHEDULING} (slower steps)")
    loops = loops_decision(
        cpu_only=cpu_only,
        xla_flags=os.environ.get("XLA_FLAGS", ""),
        env_overrides=tuple(cfg.env_overrides),
        backend_started=started,
    )
    if loops == "set":
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {GRAPHED_LOOPS}".strip()
        notes.append(f"XLA: {GRAPHED_LOOPS} (the written-out Cholesky's Newton loops as graph nodes)")
    elif loops == "note":
        notes.append(f"note: jax's GPU backend already runs, so XLA_FLAGS lacks {GRAPHED_LOOPS} (slower)")
    memory = memory_decision(
        cpu_only=cpu_only,
        backend=cfg.backend,
        user_set=any(v in os.environ for v in MEMORY_VARS),
        backend_started=started,
    )
    if memory == "set":
        os.environ[PREALLOCATE] = "false"
        if not cpu_only:
            notes.append(
                f"GPU memory: {PREALLOCATE}=false (jax's pool grows on demand; training.startup.backend_env)"
            )
    elif memory == "note":
        notes.append(f"note: jax's GPU backend already runs, so it reserved its memory pool ({PREALLOCATE})")
    decision = cpu_threads_decision(
        cpu_only=cpu_only,
        jaxlib_version=jaxlib.__version__,
        cores=len(os.sched_getaffinity(0)),
        user_set=NPROC in os.environ,
        backend_started=started,
    )
    why = f"jaxlib {jaxlib.__version__}'s batched LAPACK deadlocks a small CPU pool from 219 envs"
    if decision == "set":
        os.environ[NPROC] = "1"
        notes.append(f"CPU threads: {NPROC}=1 ({why}; training.startup.backend_env)")
    elif decision == "note":
        notes.append(
            f"note: jax's CPU backend already runs with its own thread pool ({why}): if this run stops, "
            f"set {NPROC}=1 before jax starts"
        )
    return notes
