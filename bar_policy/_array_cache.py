"""A disk cache for arrays the package computes from its own files, such as the piano's key poses.

Users: ``tasks.piano.prior.key_poses``; the tracker's random clips (``motion.generator.random_clips``)
and reference kinematics (``tasks.track.shared.ReferenceTable.build``), with ``cache=True``.

The piano's key-pose prior solves 388 IK problems in Python (``tasks.piano.prior.key_poses``): 11.5 s on
this project's 2-core CPU and 10-16 s on the H100 machine's. Every piano training start and every deploy
start of its kinematic source paid that, warm or cold. This cache keeps the result as one ``.npz`` file.

**The key.** An entry's file name is the SHA-256 of three things:

- ``parts``, what the caller says the arrays depend on (a JSON-able mapping: its config's ``repr``, the
  robot mode);
- ``package_hash()``, every file under ``bar_policy/`` (code, MJCF, meshes, shipped data), so any edit to
  the package is a miss;
- the numpy and mujoco versions the computation ran on.

An entry is therefore never served for other inputs or other code; a miss computes and stores.

**The store.** Entries sit under ``$BAR_POLICY_CACHE_DIR``, else ``$XDG_CACHE_HOME/bar_policy``, else
``~/.cache/bar_policy``, in ``arrays/``, next to the trainer's compile cache (``jax/``). They are written
through a temporary file and ``os.replace`` (``_files.write_atomic``), so a reader never sees half a file.
They are plain ``np.savez`` data, read with ``allow_pickle=False``. Failures never stop the caller:

- an entry that cannot be read, or that lacks an expected array, is logged, recomputed and replaced;
- a directory that cannot be written is logged, and the computed arrays are returned uncached.

Entries are capped at ``MAX_BYTES`` (1 GiB) together: past that, the least recently used (oldest
modification time; a hit refreshes it) are deleted after a store. Every edit to the package makes new
entries (the tracker's are 24 MB a package version), so without the cap the directory would only grow.

``BAR_POLICY_ARRAY_CACHE=0`` switches the cache off.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from bar_policy._files import package_hash, write_atomic

__all__ = ["cache_dir", "cache_key", "cached_arrays"]

_log = logging.getLogger(__name__)
SWITCH = "BAR_POLICY_ARRAY_CACHE"
"""Environment variable: ``0`` turns the cache off."""
MAX_BYTES = 1 << 30
"""The entries' total size past which the least recently used are deleted, bytes."""


def cache_dir() -> Path:
    """``$BAR_POLICY_CACHE_DIR/arrays``, else ``$XDG_CACHE_HOME/bar_policy/arrays``, else ``~/.cache/...``."""
    root = os.environ.get("BAR_POLICY_CACHE_DIR")
    if root:
        return Path(root).expanduser() / "arrays"
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "bar_policy" / "arrays"


def cache_key(name: str, parts: Mapping[str, Any]) -> str:
    """SHA-256 (hex) of ``name``, ``parts`` (as JSON), the package hash and the numpy and mujoco versions."""
    record = {
        "name": name,
        "parts": parts,
        "package": package_hash(),
        "numpy": np.__version__,
        "mujoco": mujoco.__version__,
    }
    return hashlib.sha256(json.dumps(record, sort_keys=True).encode()).hexdigest()


def cached_arrays(
    name: str,
    parts: Mapping[str, Any],
    names: tuple[str, ...],
    compute: Callable[[], Mapping[str, np.ndarray]],
    directory: Path | None = None,
    max_bytes: int = MAX_BYTES,
) -> dict[str, np.ndarray]:
    """The arrays ``compute()`` returns for ``parts``, from the disk cache when an entry is there.

    Args:
        name: what the arrays are (a file-name prefix, e.g. ``piano_key_poses``).
        parts: everything besides the package's files the arrays depend on, JSON-able.
        names: the arrays' names; an entry holding other names is recomputed.
        compute: makes the arrays (a mapping of exactly ``names`` to numpy arrays) on a miss.
        directory: where entries go (default ``cache_dir()``).
        max_bytes: the entries' total size kept after a store (least recently used deleted first).

    Returns:
        The arrays by name: loaded (bit for bit what ``compute`` returned when the entry was made) or
        computed now.

    Raises:
        ValueError: ``compute`` returned other names than ``names``.
    """

    def computed() -> dict[str, np.ndarray]:
        out = {k: np.asarray(v) for k, v in compute().items()}
        if sorted(out) != sorted(names):
            raise ValueError(f"{name}: compute() returned arrays {sorted(out)}, expected {sorted(names)}")
        return out

    if os.environ.get(SWITCH, "1") == "0":
        return computed()
    path = (directory or cache_dir()) / f"{name}-{cache_key(name, parts)[:32]}.npz"
    if path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                loaded = {k: data[k] for k in data.files}
            if sorted(loaded) == sorted(names):
                _log.info("%s: loaded %s", name, path)
                with contextlib.suppress(OSError):  # recently used: the last to be evicted
                    os.utime(path)
                return loaded
            _log.warning("%s: %s holds %s, not %s; recomputing", name, path, sorted(loaded), sorted(names))
        except (OSError, ValueError, EOFError) as e:
            why = f"{type(e).__name__}: {e}"
            _log.warning("%s: unreadable cache entry %s (%s); recomputing", name, path, why)
    out = computed()
    buf = io.BytesIO()
    np.savez(buf, **out)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, buf.getvalue())
        _log.info("%s: stored %s", name, path)
    except OSError as e:
        _log.warning("%s: cannot write the cache entry %s (%s); not cached", name, path, e)
        return out
    _evict(path.parent, max_bytes, keep=path)
    return out


def _evict(directory: Path, max_bytes: int, keep: Path) -> None:
    """Delete the least recently used ``*.npz`` entries of ``directory`` until the rest fit ``max_bytes``.

    ``keep`` (the entry just stored) is never deleted. Each deletion is logged; one that fails (another
    process deleted it first) is skipped.
    """
    entries = []
    for p in directory.glob("*.npz"):
        with contextlib.suppress(OSError):
            st = p.stat()
            entries.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in entries)
    for _, size, p in sorted(entries):
        if total <= max_bytes:
            break
        if p == keep:
            continue
        with contextlib.suppress(OSError):
            p.unlink()
            total -= size
            _log.info("array cache: evicted %s (%d bytes; entries over %d bytes)", p.name, size, max_bytes)
