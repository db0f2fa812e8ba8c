"""One log per run, as NumPy NPZ (numpy only, no pickles).

A run directory ``<dir>/<YYYYmmdd-HHMMSS>-<target>/`` holds:

- ``chunks/chunk_NNNNNN.npz``: every ``chunk_ticks`` ticks the filled buffer is handed to a writer thread
  and saved, so at most one chunk is lost if the process is killed outright;
- ``log.npz``: all ticks, written by ``close()`` (the runtime calls it in ``finally``, so it is written when
  the run ends on an exception too), plus ``meta_json`` (a 0-d string array: run metadata, mode
  transitions, timing summary, end reason);
- ``run.json``: the same metadata, for humans.

Per-tick arrays (first axis = tick): ``t`` (target clock, s), ``wall`` (s since start), ``mode`` (int8,
``safety.Mode``), ``q``/``dq``/``tau`` (measured, (T, n)), ``obs`` (T, obs_size) float32, ``action``
(T, n_actions) float32 (NaN where the policy did not run), ``q_cmd``/``dq_cmd``/``kp``/``kd``/``tau_ff``
(T, n), ``tau_cmd`` (host's MIT torque for the command at the measured state, capped, (T, n)),
``n_clipped`` (joints whose q_cmd was clipped to a limit that tick), ``n_action_clipped`` (action
entries clipped to the action bound), ``compute`` / ``infer`` / ``jitter`` (s), ``overrun`` (bool),
and one (T, 3) array per command name. ``load_log`` reads a ``log.npz`` or, when the run died before
``close``, reassembles the chunks.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["RunLog", "load_log", "log_fields"]

log = logging.getLogger(__name__)


def log_fields(
    n_joints: int, n_actions: int, obs_size: int, command_names: tuple[str, ...]
) -> dict[str, tuple[tuple[int, ...], type]]:
    """The per-tick fields of a run log: name -> (per-tick shape, dtype)."""
    n = (n_joints,)
    fields: dict[str, tuple[tuple[int, ...], type]] = {
        "t": ((), np.float64),
        "wall": ((), np.float64),
        "mode": ((), np.int8),
        "q": (n, np.float64),
        "dq": (n, np.float64),
        "tau": (n, np.float64),
        "obs": ((obs_size,), np.float32),
        "action": ((n_actions,), np.float32),
        "q_cmd": (n, np.float64),
        "dq_cmd": (n, np.float64),
        "kp": (n, np.float64),
        "kd": (n, np.float64),
        "tau_ff": (n, np.float64),
        "tau_cmd": (n, np.float64),
        "n_clipped": ((), np.int16),
        "n_action_clipped": ((), np.int16),
        "compute": ((), np.float64),
        "infer": ((), np.float64),
        "jitter": ((), np.float64),
        "overrun": ((), np.bool_),
    }
    for name in command_names:
        fields[name] = ((3,), np.float64)
    return fields


class RunLog:
    """Buffered per-tick recorder that writes NPZ chunks in the background and one ``log.npz`` at close."""

    def __init__(
        self,
        root: str | Path,
        fields: Mapping[str, tuple[tuple[int, ...], type]],
        meta: Mapping[str, Any],
        *,
        name: str = "run",
        chunk_ticks: int = 1000,
    ) -> None:
        """Create the run directory.

        Args:
            root: parent directory of run directories.
            fields: per-tick fields (``log_fields``).
            meta: JSON-serialisable run metadata.
            name: suffix of the run directory (the target name).
            chunk_ticks: ticks per chunk file.
        """
        if chunk_ticks < 1:
            raise ValueError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
        stamp = time.strftime("%Y%m%d-%H%M%S")
        root = Path(root)
        path = root / f"{stamp}-{name}"
        k = 1
        while path.exists():
            path = root / f"{stamp}-{name}-{k}"
            k += 1
        (path / "chunks").mkdir(parents=True)
        self.path = path
        self.fields = dict(fields)
        self.meta: dict[str, Any] = dict(meta)
        self.chunk_ticks = chunk_ticks
        self.ticks = 0
        self._n = 0
        self._chunk = 0
        self._buf = self._new_buffer()
        self._chunk_files: list[Path] = []
        self._queue: queue.SimpleQueue[tuple[Path, dict[str, np.ndarray]] | None] = queue.SimpleQueue()
        self._writer = threading.Thread(target=self._write_loop, name="bar-deploy-log", daemon=True)
        self._writer.start()
        self._write_errors: list[str] = []
        self.closed = False
        self._write_json(self.meta | {"status": "running"})

    def _new_buffer(self) -> dict[str, np.ndarray]:
        def empty(shape: tuple[int, ...], dt: type) -> np.ndarray:
            fill = np.nan if np.issubdtype(dt, np.floating) else 0
            return np.full((self.chunk_ticks, *shape), fill, dtype=dt)

        return {k: empty(shape, dt) for k, (shape, dt) in self.fields.items()}

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            path, arrays = item
            try:
                np.savez(path, **arrays)
            except OSError as e:  # keep running; reported at close
                self._write_errors.append(f"{path}: {e}")

    def append(self, record: Mapping[str, Any]) -> None:
        """Record one tick (name -> value); fields left out stay NaN (float fields) or 0."""
        i = self._n
        buf = self._buf
        for k, v in record.items():
            buf[k][i] = v
        self._n += 1
        self.ticks += 1
        if self._n == self.chunk_ticks:
            self._flush_chunk()

    def _flush_chunk(self) -> None:
        if self._n == 0:
            return
        arrays = {k: v[: self._n] for k, v in self._buf.items()}
        path = self.path / "chunks" / f"chunk_{self._chunk:06d}.npz"
        self._chunk_files.append(path)
        self._queue.put((path, arrays))
        self._chunk += 1
        self._buf = self._new_buffer()
        self._n = 0

    def _write_json(self, meta: Mapping[str, Any]) -> None:
        (self.path / "run.json").write_text(json.dumps(meta, indent=2, sort_keys=True, default=str))

    def close(self, **meta: Any) -> Path:
        """Flush everything, write ``log.npz`` and ``run.json`` (idempotent); returns the ``log.npz`` path."""
        out = self.path / "log.npz"
        if self.closed:
            return out
        self.closed = True
        self._flush_chunk()
        self._queue.put(None)
        self._writer.join()
        self.meta.update(meta)
        self.meta["ticks"] = self.ticks
        self.meta["status"] = "closed"
        if self._write_errors:
            self.meta["chunk_write_errors"] = self._write_errors
        arrays = _concat_chunks(self._chunk_files, self.fields)
        np.savez(out, meta_json=np.array(json.dumps(self.meta, sort_keys=True, default=str)), **arrays)
        self._write_json(self.meta)
        log.info("run log written to %s (%d ticks)", out, self.ticks)
        return out


def _concat_chunks(
    files: list[Path], fields: Mapping[str, tuple[tuple[int, ...], type]] | None
) -> dict[str, np.ndarray]:
    parts: dict[str, list[np.ndarray]] = {}
    for f in files:
        with np.load(f, allow_pickle=False) as z:
            for k in z.files:
                parts.setdefault(k, []).append(z[k])
    if parts:
        return {k: np.concatenate(v) for k, v in parts.items()}
    if fields is None:
        return {}
    return {k: np.zeros((0, *shape), dtype=dt) for k, (shape, dt) in fields.items()}


def load_log(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a run log: a ``log.npz`` file or a run directory (chunks are used when ``log.npz`` is absent).

    Returns:
        ``(arrays, meta)``: per-tick arrays (first axis = tick) and the run metadata.

    Raises:
        FileNotFoundError: nothing readable at ``path``.
    """
    path = Path(path)
    if path.is_dir():
        final = path / "log.npz"
        if final.is_file():
            path = final
        else:
            chunks = sorted((path / "chunks").glob("chunk_*.npz"))
            if not chunks:
                raise FileNotFoundError(f"{path} has neither log.npz nor chunks/chunk_*.npz")
            meta_file = path / "run.json"
            meta = json.loads(meta_file.read_text()) if meta_file.is_file() else {}
            return _concat_chunks(chunks, None), meta
    if not path.is_file():
        raise FileNotFoundError(f"no run log at {path} (give a run directory or its log.npz)")
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("a single array, not an NPZ archive")
            arrays = {k: z[k] for k in z.files if k != "meta_json"}
            meta = json.loads(str(z["meta_json"])) if "meta_json" in z.files else {}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(f"{path} is not a run log (NPZ written by bar-deploy): {e}") from None
    return arrays, meta
