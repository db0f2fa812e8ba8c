"""Executable cache: a warm start loads each compiled program instead of tracing, lowering and compiling it.

jax's persistent compilation cache keys an executable on the lowered program, so every run has to trace and
lower (seconds of Python per program) before it can hit. This cache keys the *serialised executable*
(``jax.experimental.serialize_executable``) on everything that determines the program instead, so a hit
skips the trace, the lowering and the compile. ``startup.Compiler`` consults it for every program it
submits; ``docs/startup.md`` has the measurements.

**The key** (``ExecutableCache.key``): a SHA-256 over a JSON document of

- the program's name and the jitted function's module and qualified name;
- the run's context, passed in explicitly (``run.py``: the full training config ``config_to_dict(cfg)``,
  the env config, the env's class and, for an env class outside ``bar_policy``, its source file's hash);
  the seed and every randomisation setting the programs close over live in those configs;
- ``package_hash()``: the content of every file under ``bar_policy/`` (code, XML, JSON, meshes), once per
  process;
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

Off with ``--no-executable-cache`` or ``--no-compile-cache``, and under multi-process ``jax.distributed``
(each process would load its own executable with no check that all loaded the same program).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import logging
import os
import pickle
import tempfile
import time
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "FORMAT",
    "ExecutableCache",
    "executable_cache_for",
    "library_versions",
    "package_hash",
    "platform",
    "runtime_flags",
    "signature",
    "source_hash",
]

FORMAT = 1
"""Layout of a stored entry; part of the key, bumped when the layout changes."""

MAX_BYTES = 4 << 30
"""Size the entries may total before the least recently used go (4 GiB; a GPU run's four programs are
tens of MB)."""

LIBRARIES = (
    "jax",
    "jaxlib",
    "jax-cuda12-plugin",
    "jax-cuda12-pjrt",
    "jax-cuda13-plugin",
    "jax-cuda13-pjrt",
    "libtpu",
    "mujoco",
    "mujoco-mjx",
    "brax",
    "flax",
    "optax",
    "numpy",
)
"""Distributions whose version is part of the key (None when not installed)."""

_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
_log = logging.getLogger(__name__)


@functools.cache
def package_hash() -> str:
    """SHA-256 of every file under ``bar_policy/`` (paths and contents; ``__pycache__`` left out)."""
    h = hashlib.sha256()
    for p in sorted(_PACKAGE_ROOT.rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc":
            h.update(p.relative_to(_PACKAGE_ROOT).as_posix().encode() + b"\0")
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


def source_hash(obj: Any) -> str | None:
    """SHA-256 of the source file defining ``obj``'s class.

    None when the file lies in ``bar_policy`` (``package_hash`` covers it) or there is none.
    """
    import inspect

    cls = obj if isinstance(obj, type) else type(obj)
    try:
        path = Path(inspect.getfile(cls)).resolve()
    except (TypeError, OSError):
        return None
    if path.is_relative_to(_PACKAGE_ROOT) or not path.is_file():
        return None
    return hashlib.sha256(path.read_bytes()).hexdigest()


@functools.cache
def library_versions() -> dict[str, str | None]:
    """Installed versions of ``LIBRARIES`` (``jax.__version__``/``jaxlib.__version__`` for those two)."""
    import jax
    import jaxlib

    out: dict[str, str | None] = {}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    out["jax"], out["jaxlib"] = jax.__version__, jaxlib.__version__
    return out


def platform() -> dict[str, Any]:
    """The default backend and its devices, the process count and index."""
    import jax

    devices = jax.devices()
    return {
        "backend": jax.default_backend(),
        "platform_version": devices[0].client.platform_version,
        "devices": [[d.id, d.device_kind, d.process_index] for d in devices],
        "local_devices": [d.id for d in jax.local_devices()],
        "process_count": jax.process_count(),
        "process_index": jax.process_index(),
    }


def runtime_flags() -> dict[str, str]:
    """Every jax config value but the compilation cache's own, and the XLA/JAX/LIBTPU environment."""
    import jax

    flags = {
        k: repr(v)
        for k, v in jax.config.values.items()
        if "compilation_cache" not in k and "persistent_cache" not in k
    }
    env = {
        k: v
        for k, v in os.environ.items()
        if k.startswith(("XLA_", "JAX_", "LIBTPU_")) and "COMPILATION_CACHE" not in k
    }
    return {**flags, **{f"env:{k}": v for k, v in env.items()}}


def _sharding(s: Any) -> Any:
    if s is None:
        return None
    mesh = getattr(s, "mesh", None)
    devices = getattr(mesh, "devices", None)
    if devices is not None:
        ids = [int(d.id) for d in devices.flat]
    else:
        ids = sorted(int(d.id) for d in getattr(s, "device_set", ()))
    return [repr(s), ids, getattr(s, "memory_kind", None)]


def _name(t: type) -> str:
    return f"{t.__module__}.{t.__qualname__}"


def _stable(x: Any, depth: int = 0) -> Any:
    """A description of ``x`` that is the same in every process for equal content (a tree's static data).

    Containers, numpy arrays (by content), dataclasses and objects (by their fields) are described by
    value; whatever else falls back to ``repr``, which may hold an address: then the key differs in every
    run (a miss each time), it never matches a program built for other content.
    """
    if x is None or isinstance(x, bool | int | float | complex | str | bytes):
        return repr(x)
    if isinstance(x, np.generic):
        return f"{type(x).__name__}({x!r})"
    if isinstance(x, np.ndarray):
        digest = hashlib.sha256(np.ascontiguousarray(x).tobytes()).hexdigest()
        return ["ndarray", list(x.shape), str(x.dtype), digest]
    if isinstance(x, type):
        return _name(x)
    if depth > 12:
        return repr(x)
    if isinstance(x, tuple | list):
        return [type(x).__name__, [_stable(v, depth + 1) for v in x]]
    if isinstance(x, dict):
        return ["dict", [[_stable(k, depth + 1), _stable(v, depth + 1)] for k, v in x.items()]]
    if isinstance(x, set | frozenset):
        return [type(x).__name__, sorted(json.dumps(_stable(v, depth + 1), default=repr) for v in x)]
    if dataclasses.is_dataclass(x):
        state = {f.name: getattr(x, f.name, None) for f in dataclasses.fields(x)}
    elif hasattr(x, "__dict__") and not callable(x):
        state = dict(vars(x))
    elif getattr(type(x), "__slots__", None):
        state = {k: getattr(x, k, None) for k in type(x).__slots__}
    else:
        return repr(x)
    return [_name(type(x)), _stable(state, depth + 1)]


def _tree(tree: Any) -> Any:
    """``tree`` (a ``PyTreeDef``) described with ``_stable`` node data (``str`` of it shows addresses)."""
    node = tree.node_data()
    if node is None:
        return "*"
    kind, aux = node
    return [_name(kind), _stable(aux), [_tree(c) for c in tree.children()]]


def _leaf(x: Any) -> list[Any]:
    if hasattr(x, "shape") and hasattr(x, "dtype"):
        weak = getattr(x, "weak_type", None)
        if weak is None:
            weak = getattr(getattr(x, "aval", None), "weak_type", False)
        return [list(x.shape), str(x.dtype), bool(weak), _sharding(getattr(x, "sharding", None))]
    return ["static", _name(type(x)), _stable(x)]


def signature(args: Any) -> dict[str, Any]:
    """The abstract signature of ``args``: its tree and each leaf's shape, dtype, weak type, sharding."""
    import jax

    leaves, tree = jax.tree_util.tree_flatten(args)
    return {"tree": _tree(tree), "leaves": [_leaf(x) for x in leaves]}


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

    def key(self, name: str, jitted: Any, args: tuple[Any, ...]) -> tuple[str, dict[str, Any]]:
        """``(hex key, inputs)`` of program ``name``: ``jitted`` for ``args``; inputs is what was hashed."""
        fn = getattr(jitted, "__wrapped__", jitted)
        inputs = {
            "format": FORMAT,
            "name": name,
            "function": f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', repr(fn))}",
            "context": self.context,
            "package": package_hash(),
            "libraries": library_versions(),
            "platform": platform(),
            "flags": runtime_flags(),
            "args": signature(args),
        }
        text = json.dumps(inputs, sort_keys=True, default=repr)
        return hashlib.sha256(text.encode()).hexdigest(), inputs

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.bin"

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
            compiled = deserialize_and_load(entry["executable"], entry["in_tree"], entry["out_tree"])
            os.utime(path)  # recently used: evicted last
            return compiled
        except Exception as e:  # any failure means: compile afresh
            _log.warning(
                "executable cache: entry %s of program %r unusable (%s: %s); deleted, compiling afresh",
                path.name, name, type(e).__name__, str(e)[:200],
            )  # fmt: skip
            self.delete(key)
            self.rejected.add(key)
            return None

    def store(self, key: str, inputs: Mapping[str, Any], compiled: Any) -> str:
        """Serialise ``compiled`` under ``key`` (atomically) with its JSON sidecar.

        Returns ``stored``, or ``not stored: <why>`` (an executable or tree jax cannot serialise).
        """
        from jax.experimental.serialize_executable import serialize

        try:
            executable, in_tree, out_tree = serialize(compiled)
            entry = {"format": FORMAT, "key": key, "executable": executable}
            blob = pickle.dumps({**entry, "in_tree": in_tree, "out_tree": out_tree}, pickle.HIGHEST_PROTOCOL)
            # A tree holding a class pickle cannot find again fails here, not in the next run.
            pickle.loads(pickle.dumps((in_tree, out_tree)))
        except Exception as e:  # not serialisable: run it, do not store it
            return f"not stored: {type(e).__name__}: {str(e)[:120]}"
        side = {"key": key, "bytes": len(blob), "written": time.strftime("%Y-%m-%dT%H:%M:%S"), **inputs}
        _write_atomic(self._path(key), blob)
        _write_atomic(self.directory / f"{key}.json", json.dumps(side, indent=1, default=repr).encode())
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


def _write_atomic(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def executable_cache_for(
    cfg: Any, cache_dir: Path | None, record: Mapping[str, Any], env: Any
) -> ExecutableCache | None:
    """The run's cache in ``<cache_dir>/executables``.

    None when ``cfg.executable_cache`` is off, the compile cache is off (``cache_dir`` None) or the run
    spans several processes.

    Args:
        cfg: the run's ``TrainConfig``.
        cache_dir: jax's persistent cache directory (``startup.configure_compile_cache``'s answer).
        record: the run's config record (``run._open_run``): its ``train`` and ``env`` configs go in the key.
        env: the env trained on: its class (and source, when outside ``bar_policy``) go in the key.
    """
    import jax

    if not cfg.executable_cache or cache_dir is None:
        return None
    if cfg.distributed.num_processes > 1 or jax.process_count() > 1:
        return None
    cls = type(env)
    context = {
        "train": record["train"],
        "env": record["env"] or repr(getattr(env, "config", None)),
        "env_class": f"{cls.__module__}.{cls.__qualname__}",
        "env_source": source_hash(env),
    }
    return ExecutableCache(Path(cache_dir) / "executables", context)
