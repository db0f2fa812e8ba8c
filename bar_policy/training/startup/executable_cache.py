"""Executable cache: a warm start loads each compiled program instead of tracing, lowering and compiling it.

jax's persistent compilation cache keys an executable on the lowered program, so every run has to trace and
lower (seconds of Python per program) before it can hit. This cache keys the *serialised executable*
(``jax.experimental.serialize_executable``) on everything that determines the program instead, so a hit
skips the trace, the lowering and the compile. ``startup.compiler.Compiler`` consults it for every program it
submits; ``docs/training.md`` has the measurements.

**The key** (``ExecutableCache.key``): a SHA-256 over a JSON document of

- the program's name and the jitted function's module and qualified name;
- the run's context, passed in explicitly (``executable_key.run_context`` of the run's record: the training
  config ``config_to_dict(cfg)`` less ``OUTSIDE_PROGRAMS`` (and less ``env_overrides`` when the env config
  is there to hold their effect), the env config (its reward weights by name only: ``weights_by_name``),
  the env's class and, for an env class outside ``bar_policy``, its source
  file's hash); the seed and every randomisation setting the programs close over live in those configs;
- ``package_hash()`` (these helpers live in ``executable_key``): the content of every file under
  ``bar_policy/`` (code, XML, JSON, meshes), once per process;
- ``library_versions()``: jax, jaxlib, the PJRT plugins, mujoco, mujoco-mjx, brax, flax, optax, numpy;
- ``platform()``: the backend, its version, every device's id and kind, the process count and index;
- ``runtime_flags()``: every jax config value (the matmul precision, x64, the partitioner...) but the
  cache's own, and the ``XLA_*``/``JAX_*``/``LIBTPU_*`` environment variables;
- ``signature(args)``: the argument tree and each leaf's shape, dtype, weak type and sharding (with the
  device ids), or a non-array leaf's type and repr.

**The store**: ``<jax cache dir>/executables/<key>.bin``, a pickle of the serialised executable and its
in/out tree definitions, written atomically (temp file + rename), with ``<key>.json`` naming the key's
inputs for humans. A program whose executable or trees cannot be serialised is not stored; the reason is
recorded (``ProgramTimes.executable``). **A bad entry** (unreadable, corrupt, another format, a key that
does not match, a failed ``deserialize_and_load``) logs one warning line, is deleted and the program is
compiled normally (and stored afresh): a stale or broken program is never served.

On by default on GPU backends (``--no-executable-cache`` turns it off): on one H100 two warm runs loaded all
four programs and reached the first evaluation at 22.0 s and 25.0 s instead of 35-41 s (2026-11-27). Off on
a CPU unless ``BAR_POLICY_EXECUTABLE_CACHE_ON_CPU=1``, on other backends (unmeasured), and with
``--no-compile-cache``; ``off_reason`` says which. Under several ``jax.distributed`` processes each stores and
loads its own entries (the key holds the process index), and a program is loaded only when every process
holds it (``startup.compiler.Compiler``, through ``parallel.all_agree``); otherwise every process compiles it,
as in a cold run, whose independent compiles of one program are what jax's own persistent cache serves back
too. An entry that passes that check but fails to load on one process is compiled there alone.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import json
import logging
import os
import pickle
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bar_policy._files import write_atomic
from bar_policy.training.startup import executable_key as ek

__all__ = [
    "CPU_ENV",
    "FORMAT",
    "MAX_BYTES",
    "ExecutableCache",
    "executable_cache_for",
    "executable_cache_line",
    "off_reason",
]

FORMAT = 1
"""Layout of a stored entry; part of the key, bumped when the layout changes."""

MAX_BYTES = 4 << 30
"""Size the entries may total before the least recently used go (4 GiB; a GPU run's four programs are
tens of MB)."""

CPU_ENV = "BAR_POLICY_EXECUTABLE_CACHE_ON_CPU"
"""Set to 1 to use the cache on the CPU backend: off there by default, since a deserialised CPU executable
of the brax epoch crashed jaxlib 0.10.2 (segfault) when run; the cause (LAPACK not initialised in a process
that lowered nothing) is fixed by ``_init_lazy_kernels`` (``docs/training.md``)."""

_log = logging.getLogger(__name__)


class ExecutableCache:
    """Serialised executables under ``directory``, keyed on everything that determines them (module doc).

    Args:
        directory: where the entries go (``<jax cache dir>/executables``); created.
        context: what the run's programs close over that the code does not say: the training config, the
            env config and class (JSON-able; ``repr`` for the rest).
    """

    def __init__(self, directory: str | Path, context: Mapping[str, Any], max_bytes: int = MAX_BYTES) -> None:
        self.directory = Path(directory)
        self.max_bytes = max_bytes
        self.directory.mkdir(parents=True, exist_ok=True)
        self.context = dict(context)
        self.rejected: set[str] = set()
        """Keys whose entry was bad and deleted (in this process)."""
        self._loaded: list[str] = []
        self._lock = threading.Lock()
        self._inflight = self.directory / f"inflight-{os.getpid()}.json"
        self._ban_dead_processes_loads()

    def _ban_dead_processes_loads(self) -> None:
        """Entries a process loaded and then died running (a crash, no ``confirm``): deleted and banned."""
        for record in self.directory.glob("inflight-*.json"):
            tail = record.stem.removeprefix("inflight-")
            pid = int(tail) if tail.isdigit() else 0
            if pid == os.getpid() or _alive(pid):
                continue
            with contextlib.suppress(OSError, ValueError):
                keys = json.loads(record.read_text())
                if keys:
                    _crashed_marker(self.directory).touch()
                for key in keys:
                    self.delete(key)
                    (self.directory / f"{key}.banned").touch()
                    _log.warning(
                        "executable cache: process %d died running programs loaded from entry %s; "
                        "deleted, never stored again",
                        pid,
                        key,
                    )
            record.unlink(missing_ok=True)

    def _record_loaded(self, key: str) -> None:
        """Add ``key`` to this process's in-flight record (until ``confirm``, a crash bans it).

        The crash guard of jaxlib 0.10.2's CPU loads (docs/training.md). Programs load on several threads
        (the evaluation's on a worker), so the list and its file are updated under a lock.
        """
        with self._lock:  # one writer at a time: a record written from a stale list would lose a key
            if not self._loaded:  # an exception or Ctrl-C after loading is not the program's fault
                atexit.register(self.confirm)
            self._loaded.append(key)
            write_atomic(self._inflight, json.dumps(self._loaded).encode())

    def confirm(self) -> None:
        """The loaded programs ran (the first epoch and evaluation): drop this process's in-flight record."""
        self._inflight.unlink(missing_ok=True)

    def key(self, name: str, jitted: Any, args: tuple[Any, ...]) -> tuple[str, dict[str, Any]]:
        """``(hex key, inputs)`` of program ``name``: ``jitted`` for ``args``; inputs is what was hashed."""
        fn = getattr(jitted, "__wrapped__", jitted)
        inputs = {
            "format": FORMAT,
            "name": name,
            "function": f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}",
            "context": self.context,
            "package": ek.package_hash(),
            "libraries": ek.library_versions(),
            "platform": ek.platform(),
            "flags": ek.runtime_flags(),
            "args": ek.signature(args),
        }
        text = json.dumps(inputs, sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest(), inputs

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.bin"

    def has(self, key: str) -> bool:
        """Whether an entry is stored under ``key`` (``load`` may still find it unusable)."""
        return self._path(key).exists()

    def load(self, key: str, name: str) -> Any | None:
        """The ``jax.stages.Compiled`` stored under ``key``, or None (absent, or bad: logged, deleted)."""
        path = self._path(key)
        if not path.exists():
            return None
        try:
            from jax.experimental.serialize_executable import deserialize_and_load

            entry = pickle.loads(path.read_bytes())
            if not isinstance(entry, dict) or entry.get("format") != FORMAT or entry.get("key") != key:
                raise ValueError("not an entry of this format for this key")
            _init_lazy_kernels()
            compiled = deserialize_and_load(entry["executable"], entry["in_tree"], entry["out_tree"])
            os.utime(path)  # recently used: evicted last
            self._record_loaded(key)
            return compiled
        except Exception as e:  # any failure means: compile afresh
            _log.warning(
                "executable cache: entry %s of program %r unusable (%s: %s); deleted, compiling afresh",
                path.name,
                name,
                type(e).__name__,
                str(e)[:200],
            )
            self.delete(key)
            self.rejected.add(key)
            return None

    def store(self, key: str, inputs: Mapping[str, Any], compiled: Any) -> str:
        """Serialise ``compiled`` under ``key`` (atomically) with its JSON sidecar.

        Returns ``stored``, or ``not stored: <why>`` (an executable or tree jax cannot serialise).
        """
        from jax.experimental.serialize_executable import serialize

        if (self.directory / f"{key}.banned").exists():
            return "not stored: a process crashed running it"
        try:
            executable, in_tree, out_tree = serialize(compiled)
            entry = {"format": FORMAT, "key": key, "executable": executable}
            blob = pickle.dumps({**entry, "in_tree": in_tree, "out_tree": out_tree}, pickle.HIGHEST_PROTOCOL)
            # A tree holding a class pickle cannot find again fails here, not in the next run.
            pickle.loads(pickle.dumps((in_tree, out_tree)))
        except Exception as e:  # not serialisable: run it, do not store it
            return f"not stored: {type(e).__name__}: {str(e)[:120]}"
        side = {"key": key, "bytes": len(blob), "written": time.strftime("%Y-%m-%dT%H:%M:%S"), **inputs}
        write_atomic(self._path(key), blob)
        write_atomic(self.directory / f"{key}.json", json.dumps(side, indent=1, default=repr).encode())
        self.evict(keep=key)
        return "stored"

    def evict(self, keep: str = "") -> None:
        """Delete the least recently used entries but ``keep`` (oldest mtime first) while over the limit."""
        entries = []
        for p in self.directory.glob("*.bin"):
            with contextlib.suppress(OSError):
                st = p.stat()
                entries.append((st.st_mtime, st.st_size, p.stem))
        total = sum(size for _, size, _ in entries)
        for _, size, key in sorted(entries):
            if total <= self.max_bytes:
                break
            if key == keep:
                continue
            self.delete(key)
            total -= size

    def delete(self, key: str) -> None:
        """Remove ``key``'s entry and sidecar (absent ones are fine)."""
        for p in (self._path(key), self.directory / f"{key}.json"):
            p.unlink(missing_ok=True)


def _init_lazy_kernels() -> None:
    """Fill in the kernel tables jax fills only while *lowering* a program that calls them.

    jaxlib's CPU LAPACK kernels (Cholesky, triangular solve, LU, QR, eigen-, SVD, ...) call LAPACK through
    function pointers that ``jaxlib.lapack._lapack.initialize()`` takes from scipy; jax calls it from the
    lowering rule of each linalg primitive (``lapack.prepare_lapack_call``), not at import. A process that
    loads an executable instead of lowering it never calls it, and the first LAPACK call of the loaded
    program jumps to address 0: the segfault of the brax epoch (MJX's solver factorises with
    ``potrf``) on a CPU with jaxlib 0.10.2 (docs/training.md). The GPU's hybrid (host LAPACK) kernels are
    initialised the same lazy way (``gpu_solver.initialize_hybrid_kernels``). Both calls are idempotent;
    the first loads scipy (about 0.15 s).
    """
    with contextlib.suppress(Exception):  # no LAPACK module: nothing a program could call
        from jax._src.lib import lapack

        lapack._lapack.initialize()
    with contextlib.suppress(Exception):  # no GPU plugin
        from jax._src.lib import gpu_solver

        if gpu_solver is not None and hasattr(gpu_solver, "initialize_hybrid_kernels"):
            gpu_solver.initialize_hybrid_kernels()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return pid > 0
    return pid > 0


def executable_cache_for(
    cfg: Any, cache_dir: Path | None, record: Mapping[str, Any], env: Any
) -> ExecutableCache | None:
    """The run's cache in ``<cache_dir>/executables``.

    None when ``off_reason`` gives one (switched off, no compile cache, a CPU without the opt-in, a
    backend other than a GPU) or a run crashed after loading from it (a warning line).

    Args:
        cfg: the run's ``TrainConfig``.
        cache_dir: jax's persistent cache directory (``compile_cache.configure_compile_cache``'s answer).
        record: the run's config record (``run_dir.open_run``): its ``train`` and ``env`` configs go in the
            key (``executable_key.run_context``).
        env: the env trained on: its class (and source, when outside ``bar_policy``) go in the key.
    """
    import jax

    if off_reason(cfg, cache_dir, jax.default_backend()):
        return None
    context = ek.run_context(record, env)
    cache = ExecutableCache(Path(cache_dir) / "executables", context)
    if _crashed_marker(cache.directory).exists():
        _log.warning(
            "executable cache: off, a run crashed after loading from it on this backend and jaxlib (delete "
            "%s to try again)",
            _crashed_marker(cache.directory),
        )
        return None
    return cache


def _crashed_marker(directory: Path) -> Path:
    """Left when a process died running loaded programs: the cache stays off for this backend and jaxlib."""
    import jax
    import jaxlib

    return directory / f"crashed-{jax.default_backend()}-jaxlib-{jaxlib.__version__}"


def off_reason(cfg: Any, cache_dir: Path | None, backend: str) -> str:
    """Why the run gets no executable cache, '' when it gets one (the default decision, docs/training.md).

    Args:
        cfg: the run's ``TrainConfig`` (``executable_cache``).
        cache_dir: jax's persistent cache directory, None when ``--no-compile-cache``.
        backend: ``jax.default_backend()``: ``gpu`` (CUDA or ROCm), ``cpu``, ``tpu``...
    """
    if not cfg.executable_cache:
        return "switched off, --no-executable-cache"
    if cache_dir is None:
        return "compile cache off"
    if backend == "cpu":
        return "" if os.environ.get(CPU_ENV) == "1" else f"CPU backend; {CPU_ENV}=1 turns it on"
    return "" if backend == "gpu" else f"{backend} backend, unmeasured there"


def executable_cache_line(cfg: Any, cache_dir: Path | None, cache: ExecutableCache | None) -> str:
    """The run's log line: ``executable cache: <dir> (docs/training.md)`` or ``... off (<why>)``."""
    if cache is not None:
        return f"executable cache: {cache.directory} (docs/training.md)"
    import jax

    why = off_reason(cfg, cache_dir, jax.default_backend())
    return f"executable cache: off ({why or 'a run crashed after loading from it: see the warning above'})"
