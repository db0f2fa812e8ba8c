"""One log per run: a streaming MCAP file that survives a crash, and one NPZ of every tick at the end.

A run directory ``<dir>/<YYYYmmdd-HHMMSS>-<target>/`` holds:

- ``run.mcap``: every tick as JSON messages on named topics (``mcap_log`` documents the schema), written by a
  background thread as the ticks arrive. Every ``flush_interval`` s of wall time (0.5 s) the chunk in
  progress is closed, written and ``fsync``-ed, so a SIGKILL or a power loss loses at most the last
  ``flush_interval`` s plus the writer's backlog (counted: ``log_max_backlog_ticks``). Foxglove and the
  ``mcap`` CLI open it; ``read_mcap_log`` reads it back even without its footer.
- ``log.npz``: all ticks as arrays, written (atomically, fsync-ed) by ``close()``, plus ``meta_json`` (a 0-d
  string: run metadata, mode transitions, timing summary, end reason, the stop path's outcome). The runtime
  calls ``close()`` in ``finally``, so it is written when the run ends on a signal or an exception too.
- ``run.json``: the metadata for humans, ``status: running`` until ``close()`` rewrites it with
  ``status: closed`` (both writes atomic and fsync-ed). It is strict JSON: every NaN or infinity in the
  metadata (a timing statistic of a run with no tick, say) is written as ``null``
  (``_files.strict_json``); so is ``meta_json`` in ``log.npz``.
- ``chunks/``: while the run lasts, the NPZ spill of every ``chunk_ticks`` ticks (memory stays bounded);
  removed once ``log.npz`` is on disk.

Per-tick arrays (first axis = tick): ``t`` (target clock, s), ``wall`` (s since start), ``mode`` (int8,
``safety.Mode``), ``q``/``dq``/``tau`` (measured, (T, n)), ``temperature`` (motor temperature, degC, (T, n);
NaN on targets that report none), ``obs`` (T, obs_size) float32, ``action``
(T, n_actions) float32 (NaN where the policy did not run), ``q_cmd``/``dq_cmd``/``kp``/``kd``/``tau_ff``
(T, n), ``tau_cmd`` (host's MIT torque for the command at the measured state, capped, (T, n)),
``n_clipped`` (joints whose q_cmd was clipped to a limit that tick), ``n_action_clipped`` (action
entries clipped to the action bound), ``compute`` / ``infer`` / ``jitter`` (s), ``overrun`` (bool),
and the command source's fields (``CommandSource.log_fields``): for reach one (T, 3) array per target
(``target_pos_left`` / ``target_pos_right``, chest frame, m); for tracking the reference the robot should
be at that tick, ``ref_q`` (T, n) rad, and ``ref_frame`` (T,) int32, its frame index in the clip (0 during
the start-up HOLD, which ramps to the first frame; the last frame once the clip is over). ``load_log``
reads ``log.npz``, or, for a run that never closed (killed, power loss), ``run.mcap`` (and NPZ chunks of
older runs).
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import shutil
import threading
import time
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from bar_policy._files import InputError, fsync_dir, loads_json, shorten, strict_json
from bar_policy.deploy.mcap_log import MCAP_FILE, McapRunWriter, read_mcap_log

__all__ = [
    "FLUSH_INTERVAL",
    "LogDirError",
    "LogReadError",
    "RunLog",
    "check_log_dir",
    "load_log",
    "log_fields",
]

log = logging.getLogger(__name__)

FLUSH_INTERVAL = 0.5
"""Wall time between durable flushes of ``run.mcap``, s (the log loses at most this much on a crash)."""
NOT_CLOSED = "not closed: the process ended without closing the log (killed or power loss)"
"""``end_reason`` that ``load_log`` reports for a run recovered from ``run.mcap``."""


class LogDirError(ValueError):
    """The log directory cannot be created or written."""


class LogReadError(InputError):
    """A run log that ``load_log`` cannot read: not a log written by ``bar-deploy``, truncated or corrupt."""


def log_fields(
    n_joints: int,
    n_actions: int,
    obs_size: int,
    commands: Mapping[str, tuple[tuple[int, ...], type]] | Sequence[str] = (),
) -> dict[str, tuple[tuple[int, ...], type]]:
    """The per-tick fields of a run log: name -> (per-tick shape, dtype).

    Args:
        n_joints: joints of the robot state.
        n_actions: action entries.
        obs_size: observation entries.
        commands: the command source's fields (``CommandSource.log_fields``: name -> (shape, dtype)), or
            command names, each a (3,) float64 vector (the reach targets).
    """
    n = (n_joints,)
    fields: dict[str, tuple[tuple[int, ...], type]] = {
        "t": ((), np.float64),
        "wall": ((), np.float64),
        "mode": ((), np.int8),
        "q": (n, np.float64),
        "dq": (n, np.float64),
        "tau": (n, np.float64),
        "temperature": (n, np.float64),
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
    if isinstance(commands, Mapping):
        clash = sorted(set(commands) & set(fields))
        if clash:
            raise ValueError(f"command source log fields {clash} collide with the run log's own fields")
        fields.update({k: (tuple(shape), dt) for k, (shape, dt) in commands.items()})
    else:
        fields.update({name: ((3,), np.float64) for name in commands})
    return fields


# ---------------------------------------------------------------------------------------------------
# Durable file helpers
# ---------------------------------------------------------------------------------------------------
def _write_durable(path: Path, write: Callable[[IO[bytes]], None]) -> None:
    """Write through ``<path>.partial``, fsync, rename over ``path``, fsync the directory."""
    tmp = path.with_name(path.name + ".partial")
    try:
        with tmp.open("wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)


def _json_text(meta: Mapping[str, Any], **kwargs: Any) -> str:
    """Strict JSON of the run metadata, keys sorted (``_files.strict_json``: NaN, infinities -> ``null``)."""
    return strict_json(meta, sort_keys=True, **kwargs)


def _json_bytes(meta: Mapping[str, Any]) -> bytes:
    """``run.json``'s bytes: strict JSON (``_json_text``; non-finite floats written as ``null``), indented."""
    return _json_text(meta, indent=2).encode()


def check_log_dir(root: str | Path) -> Path:
    """Create ``root`` if needed and check that a file can be written in it.

    Raises:
        LogDirError: naming the directory and the operating system's reason.
    """
    root = Path(root)
    try:
        root.mkdir(parents=True, exist_ok=True)
        probe = root / f".bar-deploy-probe-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        reason = e.strerror or str(e)
        raise LogDirError(
            f"cannot write run logs under {str(root)!r}: {reason} (give a writable --log DIR, or --no-log)"
        ) from None
    return root


# ---------------------------------------------------------------------------------------------------
# Writer
# ---------------------------------------------------------------------------------------------------
class RunLog:
    """Per-tick recorder: a durable streaming ``run.mcap``, an NPZ spill, and ``log.npz`` at close."""

    def __init__(
        self,
        root: str | Path,
        fields: Mapping[str, tuple[tuple[int, ...], type]],
        meta: Mapping[str, Any],
        *,
        name: str = "run",
        chunk_ticks: int = 1000,
        flush_interval: float = FLUSH_INTERVAL,
        labels: Mapping[str, Mapping[int, str]] | None = None,
    ) -> None:
        """Create the run directory and start the writer thread.

        Args:
            root: parent directory of run directories.
            fields: per-tick fields (``log_fields``).
            meta: JSON-serialisable run metadata.
            name: suffix of the run directory (the target name).
            chunk_ticks: ticks per NPZ spill chunk (bounds the memory of a long run).
            flush_interval: wall time between durable flushes of ``run.mcap``, s (> 0).
            labels: names of integer field values for the MCAP messages (``{"mode": {1: "DAMPING"}}``).

        Raises:
            LogDirError: the run directory or its files cannot be created.
        """
        if chunk_ticks < 1:
            raise ValueError(f"chunk_ticks must be >= 1, got {chunk_ticks}")
        if not flush_interval > 0:
            raise ValueError(f"flush_interval must be > 0 s, got {flush_interval}")
        self.fields = dict(fields)
        self.chunk_ticks = chunk_ticks
        self.flush_interval = float(flush_interval)
        start_ns = time.time_ns()
        self.meta: dict[str, Any] = {"started_unix": start_ns / 1e9} | dict(meta)
        self.path = self._make_dir(Path(root), name)
        self.ticks = 0
        self._n = 0
        self._chunk = 0
        self._buf = self._new_buffer()
        self._chunk_files: list[Path] = []
        self._write_errors: list[str] = []
        self.flushes = 0
        """Durable flushes of ``run.mcap`` so far."""
        self.max_backlog = 0
        """Most ticks ever waiting for the writer thread (what a crash could lose beyond a flush period)."""
        self._written = 0
        self.closed = False
        try:
            _write_durable(
                self.path / "run.json", lambda f: f.write(_json_bytes(self.meta | {"status": "running"}))
            )
            self._mcap_file = (self.path / MCAP_FILE).open("wb")
            self._mcap = McapRunWriter(
                self._mcap_file, self.fields, self.meta, start_unix_ns=start_ns, labels=labels
            )
            self._mcap.flush()
            self._mcap_file.flush()
            os.fsync(self._mcap_file.fileno())
            fsync_dir(self.path)
        except OSError as e:
            raise LogDirError(f"cannot write the run log in {str(self.path)!r}: {e.strerror or e}") from None
        self._queue: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        self._writer = threading.Thread(target=self._write_loop, name="bar-deploy-log", daemon=True)
        self._writer.start()

    @staticmethod
    def _make_dir(root: Path, name: str) -> Path:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        try:
            root.mkdir(parents=True, exist_ok=True)
            k = 0
            while True:
                path = root / (f"{stamp}-{name}" if k == 0 else f"{stamp}-{name}-{k}")
                try:
                    (path / "chunks").mkdir(parents=True, exist_ok=False)
                    break
                except FileExistsError:
                    k += 1
        except OSError as e:
            raise LogDirError(
                f"cannot create a run directory under {str(root)!r}: {e.strerror or e} "
                "(give a writable --log DIR, or --no-log)"
            ) from None
        fsync_dir(root)
        return path

    def _new_buffer(self) -> dict[str, np.ndarray]:
        def empty(shape: tuple[int, ...], dt: type) -> np.ndarray:
            fill = np.nan if np.issubdtype(dt, np.floating) else 0
            return np.full((self.chunk_ticks, *shape), fill, dtype=dt)

        return {k: empty(shape, dt) for k, (shape, dt) in self.fields.items()}

    # -- the loop's side (cheap: copy into the buffer, hand a reference to the writer) ----------------
    def append(self, record: Mapping[str, Any]) -> None:
        """Record one tick (name -> value); fields left out stay NaN (float fields) or 0."""
        if self.closed:
            raise RuntimeError("the run log is closed")
        i = self._n
        buf = self._buf
        for k, v in record.items():
            buf[k][i] = v
        # Rows are never written again once appended, so the writer thread may read them at leisure.
        self._queue.put(("tick", buf, i, self.ticks, time.time_ns()))
        self._n += 1
        self.ticks += 1
        if self._n == self.chunk_ticks:
            self._spill_chunk()

    def transition(self, transition: Mapping[str, Any]) -> None:
        """Record a mode change (``Transition.to_dict()``) on ``/safety/transition``."""
        if not self.closed:
            self._queue.put(("transition", dict(transition), time.time_ns()))

    def _spill_chunk(self) -> None:
        if self._n == 0:
            return
        arrays = {k: v[: self._n] for k, v in self._buf.items()}
        path = self.path / "chunks" / f"chunk_{self._chunk:06d}.npz"
        self._chunk_files.append(path)
        self._queue.put(("chunk", path, arrays))
        self._chunk += 1
        self._buf = self._new_buffer()
        self._n = 0

    # -- the writer thread -------------------------------------------------------------------------
    def _error(self, what: str, e: BaseException) -> None:
        msg = f"{what}: {type(e).__name__}: {e}"
        if not self._write_errors:
            log.error("run log: %s (further errors counted)", msg)
        self._write_errors.append(msg)

    def _durable_flush(self) -> None:
        try:
            self._mcap.flush()
            self._mcap_file.flush()
            os.fsync(self._mcap_file.fileno())
            self.flushes += 1
        except (OSError, ValueError) as e:
            self._error("flush run.mcap", e)

    def _write_loop(self) -> None:
        dirty = False
        next_flush = time.monotonic() + self.flush_interval
        while True:
            try:
                item = self._queue.get(timeout=max(next_flush - time.monotonic(), 0.0))
            except queue.Empty:
                item = ("idle",)
            kind = item[0]
            if kind == "tick":
                _, buf, i, tick, wall_ns = item
                try:
                    self._mcap.write_tick(tick, {k: v[i] for k, v in buf.items()}, wall_ns)
                except Exception as e:
                    self._error(f"tick {tick} to run.mcap", e)
                self._written = tick + 1
                self.max_backlog = max(self.max_backlog, self.ticks - self._written)
                dirty = True
            elif kind == "transition":
                try:
                    self._mcap.write_transition(item[1], item[2])
                except Exception as e:
                    self._error("transition to run.mcap", e)
                dirty = True
            elif kind == "chunk":
                _, path, arrays = item
                try:
                    np.savez(path, **arrays)
                except OSError as e:
                    self._error(f"spill {path.name}", e)
            elif kind == "close":
                try:
                    self._mcap.finish(item[1])
                    self._mcap_file.flush()
                    os.fsync(self._mcap_file.fileno())
                except Exception as e:
                    self._error("finish run.mcap", e)
                with contextlib.suppress(OSError):
                    self._mcap_file.close()
                return
            if time.monotonic() >= next_flush:
                if dirty:
                    self._durable_flush()
                    dirty = False
                next_flush = time.monotonic() + self.flush_interval

    # -- closing -----------------------------------------------------------------------------------
    def close(self, **meta: Any) -> Path:
        """Finish ``run.mcap``, write ``log.npz`` and ``run.json`` (idempotent); returns the ``log.npz`` path.

        ``meta`` is merged into the run metadata (end reason, transitions, timing, counts).
        """
        out = self.path / "log.npz"
        if self.closed:
            return out
        self.closed = True
        self._spill_chunk()
        self.meta.update(meta)
        self.meta["ticks"] = self.ticks
        self.meta["status"] = "closed"
        self.meta["log_flush_interval_s"] = self.flush_interval
        # The writer finishes the MCAP with the final metadata; the counters it adds are its own.
        end = dict(self.meta)
        self._queue.put(("close", end))
        self._writer.join()
        self.meta["log_flushes"] = self.flushes
        self.meta["log_max_backlog_ticks"] = self.max_backlog
        if self._write_errors:
            self.meta["log_write_errors"] = self._write_errors[:20]
            self.meta["log_write_error_count"] = len(self._write_errors)
        arrays = _concat_chunks(self._chunk_files, self.fields)
        meta_json = np.array(_json_text(self.meta))

        def write_npz(f: IO[bytes]) -> None:
            np.savez(f, meta_json=meta_json, **arrays)

        _write_durable(out, write_npz)
        _write_durable(self.path / "run.json", lambda f: f.write(_json_bytes(self.meta)))
        shutil.rmtree(self.path / "chunks", ignore_errors=True)
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


# ---------------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any]:
    """``run.json`` as a dict; ``{}`` when it is missing, malformed or not an object (it only informs)."""
    try:
        value = loads_json(path.read_bytes(), str(path), LogReadError)
    except (OSError, LogReadError):
        return {}
    return value if isinstance(value, dict) else {}


def _load_mcap(path: Path, run_json: dict[str, Any]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    try:
        rec = read_mcap_log(path)
    except LogReadError:
        raise
    except (ValueError, TypeError, KeyError, RecursionError, EOFError) as e:
        raise LogReadError(
            f"{path} is not a run log (MCAP written by bar-deploy): {shorten(e, 500)}"
        ) from None
    meta = run_json | rec.meta
    if not rec.complete:
        meta["status"] = "running"
        meta["end_reason"] = NOT_CLOSED
        meta["recovered_from"] = path.name
        if rec.error:
            meta["recovery_stopped_at"] = rec.error
        meta.setdefault("transitions", rec.transitions)
    meta["ticks"] = int(rec.arrays["t"].shape[0]) if "t" in rec.arrays else 0
    return rec.arrays, meta


def load_log(path: str | Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a run log: a run directory, its ``log.npz`` or its ``run.mcap``.

    A directory is read from ``log.npz`` when the run closed, else from ``run.mcap`` (complete or cut off by
    a crash: everything up to the last durable flush), else from NPZ chunks (logs of older versions). A run
    recovered without ``close()`` has ``meta["status"] == "running"`` and ``meta["end_reason"]`` saying so.

    Returns:
        ``(arrays, meta)``: per-tick arrays (first axis = tick) and the run metadata.

    Raises:
        FileNotFoundError: nothing at ``path``.
        LogReadError: (an ``_files.InputError``, a ``ValueError``) the file is not a run log, or a corrupt
            one: the only error for malformed content, whatever the bytes.
    """
    path = Path(path)
    if path.is_dir():
        run_json = _read_json(path / "run.json")
        if (path / "log.npz").is_file():
            path = path / "log.npz"
        elif (path / MCAP_FILE).is_file():
            try:
                return _load_mcap(path / MCAP_FILE, run_json)
            except ValueError as e:
                chunks = sorted((path / "chunks").glob("chunk_*.npz"))
                if not chunks:
                    raise LogReadError(
                        f"run {path} has no log.npz and its {MCAP_FILE} is unreadable: {shorten(e, 500)}"
                    ) from None
                return _read_chunks(path, chunks), run_json
        else:
            chunks = sorted((path / "chunks").glob("chunk_*.npz"))
            if not chunks:
                raise FileNotFoundError(f"{path} has neither log.npz, {MCAP_FILE} nor chunks/chunk_*.npz")
            return _read_chunks(path, chunks), run_json
    if not path.is_file():
        raise FileNotFoundError(
            f"no run log at {path} (give a run directory, its log.npz or its {MCAP_FILE})"
        )
    if path.suffix == ".mcap":
        return _load_mcap(path, _read_json(path.parent / "run.json"))
    try:
        if path.stat().st_size == 0:
            raise ValueError("the file is empty")
        z = np.load(path, allow_pickle=False)
        if not hasattr(z, "files"):
            raise ValueError("a single array, not an NPZ archive")
        with z:
            arrays = {k: z[k] for k in z.files if k != "meta_json"}
            meta = (
                loads_json(str(z["meta_json"]), "meta_json", LogReadError) if "meta_json" in z.files else {}
            )
        if not isinstance(meta, dict):
            raise ValueError(f"meta_json is a JSON {type(meta).__name__}, not an object")
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise LogReadError(
            f"{path} is not a run log (NPZ written by bar-deploy): {shorten(e, 500)}"
        ) from None
    return arrays, meta


def _read_chunks(run: Path, chunks: list[Path]) -> dict[str, np.ndarray]:
    """The NPZ chunks of a run that never closed, concatenated; ``LogReadError`` when one is corrupt."""
    try:
        return _concat_chunks(chunks, None)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise LogReadError(f"run {run}: its NPZ chunks are unreadable: {shorten(e, 500)}") from None
